/* A minimal crtend_so for the stand-in bionic sysroot of tests/android: like bionic's
 * libc/arch-common/bionic/crtend_so.S, a non-executable-stack note and the .eh_frame terminator. */
	.section .note.GNU-stack, "", %progbits

	.section .eh_frame, "a", @progbits
	.balign 4
	.type	__FRAME_END__, @object
	.size	__FRAME_END__, 4
__FRAME_END__:
	.zero	4
