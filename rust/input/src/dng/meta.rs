//! What a DNG's directories say about the capture, read from rawler's parse of them: the raw
//! image's directory, CFA order, active area, black levels, ISO and exposure time, and the
//! helpers that read tag values.

use std::path::Path;

use noisecal_core::CfaPattern;
use noisecal_core::model::layout::CfaColor;
use rawler::formats::tiff::{IFD, Value};

use super::DngError;
use super::tags::Tag;

const PHOTOMETRIC_CFA: u64 = 32803;
const PHOTOMETRIC_LINEAR_RAW: u64 = 34892;

pub(super) fn value(ifd: &IFD, t: Tag) -> Option<&Value> {
    ifd.get_entry(t.to_u16()).map(|e| &e.value)
}

pub(super) fn has(ifd: &IFD, t: Tag) -> bool {
    ifd.get_entry(t.to_u16()).is_some()
}

/// The directories a pointer tag (SubIFDs, ExifIFD) leads to.
pub(super) fn subs(ifd: &IFD, t: Tag) -> Option<&Vec<IFD>> {
    ifd.sub_ifds().get(&t.to_u16())
}

/// The specification's name of a tag noisecal knows (its number for any other).
pub(super) fn tag_name(t: Tag) -> String {
    t.name().map_or_else(|| t.to_u16().to_string(), str::to_string)
}

pub(super) fn find<'a>(ifds: &[&'a IFD], t: Tag) -> Option<&'a Value> {
    ifds.iter().find_map(|ifd| value(ifd, t))
}

/// Element `i` of a numeric value as f64 (rationals divided out; a zero denominator gives None).
pub(super) fn num(v: &Value, i: usize) -> Option<f64> {
    match v {
        Value::Byte(x) => x.get(i).map(|&a| a as f64),
        Value::Short(x) => x.get(i).map(|&a| a as f64),
        Value::Long(x) => x.get(i).map(|&a| a as f64),
        Value::SByte(x) => x.get(i).map(|&a| a as f64),
        Value::SShort(x) => x.get(i).map(|&a| a as f64),
        Value::SLong(x) => x.get(i).map(|&a| a as f64),
        Value::Rational(x) => x.get(i).filter(|r| r.d != 0).map(|r| r.n as f64 / r.d as f64),
        Value::SRational(x) => x.get(i).filter(|r| r.d != 0).map(|r| r.n as f64 / r.d as f64),
        Value::Float(x) => x.get(i).map(|&a| a as f64),
        Value::Double(x) => x.get(i).copied(),
        _ => None,
    }
}

pub(super) fn nums(v: &Value) -> Vec<f64> {
    (0..v.count()).map(|i| num(v, i).unwrap_or(f64::NAN)).collect()
}

/// First element of an unsigned integer tag.
pub(super) fn uint(ifd: &IFD, t: Tag) -> Option<u64> {
    match value(ifd, t)? {
        Value::Byte(x) => x.first().map(|&a| a as u64),
        Value::Short(x) => x.first().map(|&a| a as u64),
        Value::Long(x) => x.first().map(|&a| a as u64),
        _ => None,
    }
}

pub(super) fn ascii(ifds: &[&IFD], t: Tag) -> String {
    match find(ifds, t) {
        Some(Value::Ascii(a)) => a.strings().first().map(|s| s.trim().to_string()).unwrap_or_default(),
        _ => String::new(),
    }
}

// ---------------------------------------------------------------------------------------------
// Structure

/// The full-resolution raw image: NewSubFileType 0 in the IFD chain or its SubIFDs, CFA preferred.
pub(super) fn find_raw_ifd<'a>(path: &Path, chain: &[&'a IFD]) -> Result<&'a IFD, DngError> {
    fn collect<'a>(ifd: &'a IFD, out: &mut Vec<&'a IFD>) {
        out.push(ifd);
        if let Some(subs) = subs(ifd, Tag::SubIfds) {
            for s in subs {
                collect(s, out);
            }
        }
    }
    let mut all = Vec::new();
    for ifd in chain {
        collect(ifd, &mut all);
    }
    let main: Vec<&IFD> = all
        .into_iter()
        .filter(|ifd| uint(ifd, Tag::NewSubfileType).unwrap_or(0) == 0)
        .filter(|ifd| has(ifd, Tag::StripOffsets) || has(ifd, Tag::TileOffsets))
        .collect();
    if let Some(raw) = main.iter().find(|ifd| uint(ifd, Tag::PhotometricInterpretation) == Some(PHOTOMETRIC_CFA)) {
        return Ok(raw);
    }
    if main.iter().any(|ifd| uint(ifd, Tag::PhotometricInterpretation) == Some(PHOTOMETRIC_LINEAR_RAW)) {
        return Err(DngError::unsupported(
            path,
            "this DNG holds demosaiced (LinearRaw) data, not the sensor's CFA mosaic; capture RAW_SENSOR \
             frames (or convert without demosaicing)",
        ));
    }
    Err(DngError::decode(path, "no full-resolution CFA raw image found in the DNG"))
}

pub(super) fn read_cfa(path: &Path, raw: &IFD) -> Result<CfaPattern, DngError> {
    let pattern = value(raw, Tag::CfaPattern).ok_or(DngError::MissingTag {
        path: path.to_path_buf(),
        tag: "CFAPattern (33422)",
        fix: "the raw image does not say its colour filter order; re-export the DNG with its CFA tags",
    })?;
    let n = pattern.count();
    let (rows, cols) = match value(raw, Tag::CfaRepeatPatternDim) {
        Some(v) if v.count() >= 2 => (num(v, 0).unwrap_or(0.0) as usize, num(v, 1).unwrap_or(0.0) as usize),
        _ if n == 4 => (2, 2),
        _ => {
            return Err(DngError::MissingTag {
                path: path.to_path_buf(),
                tag: "CFARepeatPatternDim (33421)",
                fix: "the CFA pattern size is not given; re-export the DNG with its CFA tags",
            });
        }
    };
    if (rows, cols) != (2, 2) {
        let xtrans = if (rows, cols) == (6, 6) { " (Fujifilm X-Trans)" } else { "" };
        return Err(DngError::unsupported(
            path,
            format!(
                "CFA repeat pattern {rows}×{cols}{xtrans} is not a 2×2 Bayer mosaic; noisecal supports \
                 RGGB/BGGR/GRBG/GBRG sensors only"
            ),
        ));
    }
    if n != 4 {
        return Err(DngError::decode(path, format!("CFAPattern has {n} entries for a 2×2 pattern")));
    }
    let planes: Vec<f64> = value(raw, Tag::CfaPlaneColor).map(nums).unwrap_or_else(|| vec![0.0, 1.0, 2.0]);
    let mut colors = [CfaColor::Green; 4];
    let mut codes = [0u8; 4];
    for (i, c) in colors.iter_mut().enumerate() {
        let idx = num(pattern, i).unwrap_or(f64::NAN);
        let plane = planes.get(idx as usize).copied().filter(|_| idx >= 0.0).unwrap_or(f64::NAN);
        codes[i] = plane as u8;
        *c = match plane as i64 {
            0 => CfaColor::Red,
            1 => CfaColor::Green,
            2 => CfaColor::Blue,
            _ => {
                return Err(DngError::unsupported(
                    path,
                    format!(
                        "CFA colour code {plane} (0=R 1=G 2=B 3=C 4=M 5=Y 6=W) is not an RGB Bayer filter; \
                         noisecal supports RGGB/BGGR/GRBG/GBRG sensors only"
                    ),
                ));
            }
        };
    }
    CfaPattern::from_colors(colors).ok_or_else(|| {
        DngError::unsupported(
            path,
            format!("CFA pattern {codes:?} (0=R 1=G 2=B) is not a Bayer order (RGGB, BGGR, GRBG or GBRG)"),
        )
    })
}

/// `ActiveArea` as (top, left, bottom, right); the whole image when absent.
pub(super) fn active_area(
    path: &Path,
    raw: &IFD,
    w: usize,
    h: usize,
) -> Result<(usize, usize, usize, usize), DngError> {
    let Some(v) = value(raw, Tag::ActiveArea) else {
        return Ok((0, 0, h, w));
    };
    let a: Vec<f64> = nums(v);
    if a.len() != 4 || a.iter().any(|x| !x.is_finite() || *x < 0.0) {
        return Err(DngError::decode(path, format!("ActiveArea {a:?} is not 4 non-negative numbers")));
    }
    let (t, l, b, r) = (a[0] as usize, a[1] as usize, a[2] as usize, a[3] as usize);
    // Saturating: a huge value (an f64 far beyond usize) must fail here as not fitting, not overflow.
    if t.saturating_add(2) > b || l.saturating_add(2) > r || b > h || r > w {
        return Err(DngError::decode(path, format!("ActiveArea {t},{l},{b},{r} does not fit the {w}×{h} image")));
    }
    Ok((t, l, b, r))
}

/// Black level per CFA position of the active area: the mean, over that position's pixels, of the
/// `BlackLevel` pattern (relative to the active area's origin, any repeat size) plus
/// `BlackLevelDeltaH` of the pixel's column and `BlackLevelDeltaV` of its row.
pub(super) fn black_levels(path: &Path, raw: &IFD, aw: usize, ah: usize) -> Result<[f32; 4], DngError> {
    let (rr, rc) = match value(raw, Tag::BlackLevelRepeatDim) {
        Some(v) => (num(v, 0).unwrap_or(0.0) as usize, num(v, 1).unwrap_or(0.0) as usize),
        None => (1, 1),
    };
    if rr == 0 || rc == 0 || rr > 64 || rc > 64 {
        return Err(DngError::decode(path, format!("BlackLevelRepeatDim {rr}×{rc} is invalid")));
    }
    let mut levels = value(raw, Tag::BlackLevel).map(nums).unwrap_or_else(|| vec![0.0]);
    if levels.iter().any(|x| !x.is_finite()) {
        return Err(DngError::decode(path, format!("BlackLevel {levels:?} is not a list of numbers")));
    }
    if levels.len() == 1 {
        levels = vec![levels[0]; rr * rc];
    }
    if levels.len() != rr * rc {
        return Err(DngError::decode(
            path,
            format!("BlackLevel has {} values but BlackLevelRepeatDim says {rr}×{rc}", levels.len()),
        ));
    }
    let delta = |t: Tag, n: usize| -> Vec<f64> {
        value(raw, t)
            .map(nums)
            .unwrap_or_default()
            .into_iter()
            .take(n)
            .map(|x| if x.is_finite() { x } else { 0.0 })
            .collect()
    };
    let dh = delta(Tag::BlackLevelDeltaH, aw);
    let dv = delta(Tag::BlackLevelDeltaV, ah);
    let parity_mean = |d: &[f64], parity: usize| -> f64 {
        let sel: Vec<f64> = d.iter().skip(parity).step_by(2).copied().collect();
        if sel.is_empty() { 0.0 } else { sel.iter().sum::<f64>() / sel.len() as f64 }
    };
    // Exact mean over the active area's pixels of each position: count the rows (columns) of each
    // parity that fall on each row (column) of the repeat pattern.
    let residue_counts = |len: usize, parity: usize, period: usize| -> Vec<f64> {
        let mut counts = vec![0.0; period];
        for i in (parity..len).step_by(2) {
            counts[i % period] += 1.0;
        }
        counts
    };
    let mut black = [0f32; 4];
    for (pos, b) in black.iter_mut().enumerate() {
        let (r, c) = (pos >> 1, pos & 1);
        let rows = residue_counts(ah, r, rr);
        let cols = residue_counts(aw, c, rc);
        let mut sum = 0.0;
        let mut weight = 0.0;
        for (a, &nr) in rows.iter().enumerate() {
            for (k, &nc) in cols.iter().enumerate() {
                sum += nr * nc * levels[a * rc + k];
                weight += nr * nc;
            }
        }
        let base = if weight > 0.0 { sum / weight } else { levels[(r % rr) * rc + c % rc] };
        *b = (base + parity_mean(&dh, c) + parity_mean(&dv, r)) as f32;
    }
    Ok(black)
}

pub(super) fn read_iso(path: &Path, ifds: &[&IFD]) -> Result<u32, DngError> {
    let positive = |t: Tag| find(ifds, t).and_then(|v| num(v, 0)).filter(|x| x.is_finite() && *x >= 1.0);
    let extended = || positive(Tag::IsoSpeed).or_else(|| positive(Tag::RecommendedExposureIndex));
    let iso = match positive(Tag::IsoSpeedRatings) {
        // 65535 means "65535 or more" (EXIF 2.3): the exact value is in ISOSpeed / REI.
        Some(x) if x >= 65535.0 => extended().unwrap_or(x),
        Some(x) => x,
        None => extended().ok_or(DngError::MissingTag {
            path: path.to_path_buf(),
            tag: "ISOSpeedRatings / PhotographicSensitivity (0x8827)",
            fix: "the DNG does not record its ISO; capture with an app that writes it (Android's DngCreator \
                  and the noisecal app do), or add it with `exiftool -ISO=<value> FILE`",
        })?,
    };
    Ok(iso.round().min(u32::MAX as f64) as u32)
}

pub(super) fn read_exposure(path: &Path, ifds: &[&IFD]) -> Result<u64, DngError> {
    let v = find(ifds, Tag::ExposureTime).ok_or(DngError::MissingTag {
        path: path.to_path_buf(),
        tag: "ExposureTime (0x829A)",
        fix: "the DNG does not record its exposure time; capture with an app that writes it (Android's \
              DngCreator and the noisecal app do), or add it with `exiftool -ExposureTime=<seconds> FILE`",
    })?;
    let ns = match v {
        Value::Rational(r) if !r.is_empty() && r[0].d != 0 => {
            let (n, d) = (r[0].n as u128, r[0].d as u128);
            ((n * 1_000_000_000 + d / 2) / d).min(u64::MAX as u128) as u64
        }
        other => match num(other, 0) {
            Some(s) if s.is_finite() && s > 0.0 => (s * 1e9).round().min(u64::MAX as f64) as u64,
            _ => 0,
        },
    };
    if ns == 0 {
        return Err(DngError::decode(path, "ExposureTime is zero or not a number"));
    }
    Ok(ns)
}
