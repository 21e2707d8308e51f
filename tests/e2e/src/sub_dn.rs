//! The 8-bit sensor with sub-DN noise of the dark-end tests (`tests/sub_dn_pattern.rs`,
//! `tests/variance_at_black.rs`): EMVA 1288 set 002's kind of camera.

use noisecal_sim::SensorModel;

/// An 8-bit sensor with black `black` DN, the reference at `iso / 2` and the target at `iso`
/// (analog), Gaussian read noise of `read_dn` after the gain, a pattern of `dsnu_dn` after the
/// gain (the same at both ISOs), nothing else structured.
pub fn sensor_8bit(black: f32, iso: u32, read_dn: f32, dsnu_dn: f32) -> SensorModel {
    let mut m = SensorModel::phone_10bit();
    m.black = [black; 4];
    m.white = 255;
    m.base_iso = iso / 2;
    m.max_analog_iso = iso;
    m.electrons_per_dn = 60.0;
    m.full_well_e = 7000.0;
    m.gain_error_per_stop = 0.0;
    m.read_noise_pre_e = 0.0;
    m.read_noise_post_dn = read_dn;
    m.read_noise_dof = None;
    m.dsnu_post_dn = dsnu_dn;
    m.row_noise_pre_e = 0.0;
    m.row_noise_post_dn = 0.0;
    m.bias_dn = [0.0; 4];
    m.jitter_px = 0.0;
    m
}
