//! Shared by the CLI's integration tests (`mod support;`).

/// The arguments of `noisecal simulate` for a small session: a `width`×`height` sensor, `frames`
/// a burst at each of `isos` (comma-separated) and EV step (`ev` as given, e.g. `--ev=-1,1`),
/// then `rest` (where to write, and any other flag).
pub fn simulate<'a>(
    (width, height): (&'a str, &'a str),
    frames: &'a str,
    isos: &'a str,
    ev: &'a str,
    rest: &[&'a str],
) -> Vec<&'a str> {
    let mut args = vec!["simulate", "--width", width, "--height", height, "--frames", frames, "--isos", isos, ev];
    args.extend_from_slice(rest);
    args
}
