//! A pack file truncated while `synth` or `renoise` holds it open (`open_pack`): the ISOs not yet
//! decoded still decode from the copy read at open, and opening the truncated file again is an
//! error that names it. A mapped pack raised SIGBUS here, killing the process (and this test).

mod support;

use noisecal_core::model::structure::Components;
use noisecal_core::resolve::ModelKind;
use noisecal_input::files::{open_pack, resolve_pack};

#[test]
fn a_pack_truncated_under_an_open_one_is_an_error_not_a_crash() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (cal, pack) = (dir.path().join("cal"), dir.path().join("p.pack"));
    let cal_s = cal.to_str().expect("utf-8");
    let r = support::run_quiet(support::simulate(("96", "64"), "3", "200,800", "--ev=-1,0,1", &["--dngs", cal_s]));
    assert!(r.ok, "simulate: {}", r.stderr);
    let r = support::run_quiet(["calibrate", cal_s, "-o", pack.to_str().expect("utf-8")]);
    assert!(r.ok, "calibrate: {}", r.stderr);
    let len = std::fs::metadata(&pack).expect("pack").len();

    let lazy = open_pack(&pack).expect("open");
    // Another program cuts the file to its first bytes while it is open: nothing is decoded yet.
    std::fs::OpenOptions::new().write(true).open(&pack).expect("open for writing").set_len(64).expect("truncate");
    for iso in [200, 800, 400] {
        let (_, resolved) = resolve_pack(&lazy, &pack, iso, ModelKind::Noisecal, Components::ALL, false)
            .unwrap_or_else(|e| panic!("ISO {iso} from the pack opened before the cut: {e:#}"));
        assert_eq!(resolved.model.iso, iso);
    }
    let e = format!("{:#}", open_pack(&pack).expect_err("a truncated pack"));
    assert!(e.contains(&pack.display().to_string()), "{e}");
    assert!(len > 64, "the pack was longer than what was left of it");
}
