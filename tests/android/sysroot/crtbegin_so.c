/* A minimal crtbegin_so for the stand-in bionic sysroot of tests/android (link check only: the app's
 * real library is linked by the NDK with bionic's own crtbegin_so.o). What it defines mirrors
 * bionic's libc/arch-common/bionic/crtbegin_so.c: the library's hidden __dso_handle (Rust's std
 * passes it to __cxa_thread_atexit_impl for thread-local destructors), the destructor that runs
 * __cxa_finalize when the library is unloaded, and the hidden atexit() over __cxa_atexit. */

extern void __cxa_finalize(void *);
extern int __cxa_atexit(void (*)(void *), void *, void *);

__attribute__((visibility("hidden"))) void *__dso_handle = &__dso_handle;

__attribute__((destructor)) static void __on_dlclose(void) {
  __cxa_finalize(&__dso_handle);
}

__attribute__((visibility("hidden"))) int atexit(void (*func)(void)) {
  return __cxa_atexit((void (*)(void *))func, (void *)0, &__dso_handle);
}
