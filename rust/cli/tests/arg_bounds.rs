//! Numbers that size allocations or loops are bounded when the command line is parsed.

mod support;

fn refused(args: &[&str], expect: &str) {
    let out = support::run(args);
    assert!(!out.ok, "{args:?} was accepted");
    assert!(out.stderr.contains(expect), "{args:?}: {}", out.stderr);
}

#[test]
fn absurd_numbers_are_refused_with_the_range() {
    refused(&["eval", "--pack", "p.pack", "held", "--seeds", "4294967295"], "not in 1..=64");
    refused(&["eval", "--pack", "p.pack", "held", "--group-bins", "0"], "give 1 to");
    refused(&["simulate", "--padding", "4294967295", "--rec", "x.rec"], "at most 65536");
    refused(&["simulate", "--width", "4000000000", "--dngs", "d"], "not in 2..=16384");
    refused(&["simulate", "--frames", "0", "--dngs", "d"], "not in 1..=1024");
    refused(&["demo", "--width", "1"], "not in 2..=16384");
    refused(&["calibrate", "caps", "-o", "p.pack", "--bin-width", "0"], "0 is not a bin width: give 1 to 4096");
    refused(&["calibrate", "caps", "-o", "p.pack", "--flat-k", "NaN"], "finite number above 0");
    refused(&["calibrate", "caps", "-o", "p.pack", "--flat-k=-1"], "finite number above 0");
}
