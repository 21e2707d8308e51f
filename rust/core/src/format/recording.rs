//! Raw recordings: the exact stream of (metadata, plane bytes, row stride) the app hands to the
//! core, so a device session replays on a desktop to the same pack. A pure codec: what the bytes
//! hold, in both directions, with the framing of [`codec`] (a record stream).
//!
//! Format v1, all integers little-endian (simple enough to read from Kotlin or Python):
//! ```text
//! magic "NCALREC\0" | version u16 | header_len u32 | header | crc32(header) u32
//! header: width u32, height u32, cfa u8 (0 RGGB, 1 BGGR, 2 GRBG, 3 GBRG), white u16,
//!         black f32×4, reference_iso u32, bin_width u16 (0 = default),
//!         make_len u16, make utf-8, model_len u16, model utf-8
//! records, each: tag u8, payload, crc32(tag + payload) u32          (tags: [`RecordTag`])
//!   1 BeginStep    exposure_ns u64
//!   2 Frame        iso u32, exposure_ns u64, has_black u8, black f32×4, width u32, height u32,
//!                  row_stride u32, pixel_stride u32, data_len u32, data
//!   3 NoiseProfile iso u32, (S, O) f64 × 4 positions
//!   4 BeginDark    (no payload: the frames up to the next BeginStep are dark frames)
//!   255 End        frames u64
//! ```
//! A recording without an End record (an interrupted capture) reads up to its last whole record.
//! Only a missing tail is an interruption: a damaged record in the middle (bad checksum, unknown
//! tag, a frame length its geometry cannot hold, a length running past the end of a file that
//! still ends with its End record), a frame record repeated byte for byte, an End record whose
//! frame count differs from the frames read, and bytes after the End record are errors naming the
//! record's index and byte offset.
//!
//! - [`RecordingWriter`] writes record by record ([`RecordingWriter::resume`] continues a
//!   recording cut back to a [`RecordingMark`], as a restored app session does).
//! - [`RecordingReader`] reads record by record from any `Read`, or from bytes
//!   ([`RecordingReader::from_bytes`], the entry point for fuzzing: no allocation beyond the input).
//! - [`TeeCheckpoint`] is the app's checkpoint: a session checkpoint together with the mark of the
//!   recording it was teeing into.

use std::collections::HashMap;
use std::io::{self, Read, Seek, SeekFrom, Write};

use serde::{Deserialize, Serialize};

use super::codec;
use crate::calibrate::meta::FrameMeta;
use crate::error::CodecError;
use crate::model::layout::{CfaPattern, POSITIONS, SensorLayout};
use crate::model::pack::NoiseProfile;

pub const RECORDING_MAGIC: &[u8; 8] = b"NCALREC\0";
pub const RECORDING_VERSION: u16 = 1;
const WHAT: &str = "recording";
/// A frame record's plane longer than this is refused as implausible (a damaged length field).
const MAX_FRAME_BYTES: u64 = 1 << 31;
/// The largest sensor a header may claim: a pack's limit per side, and 2^28 pixels in all.
const MAX_SIDE: u32 = crate::model::pack::MAX_SIDE;
const MAX_PIXELS: u64 = 1 << 28;

/// The session a recording belongs to.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordingHeader {
    pub layout: SensorLayout,
    pub reference_iso: u32,
    /// 0 = the default for the bit depth.
    pub bin_width: u16,
    pub make: String,
    pub model: String,
}

/// One frame as the app handed it over.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordedFrame {
    pub meta: FrameMeta,
    pub width: u32,
    pub height: u32,
    pub row_stride: u32,
    pub pixel_stride: u32,
    pub data: Vec<u8>,
}

impl RecordedFrame {
    pub fn view(&self) -> Result<crate::FrameView<'_>, crate::error::FrameError> {
        crate::FrameView::from_le_bytes(
            &self.data,
            self.width as usize,
            self.height as usize,
            self.row_stride as usize,
            self.pixel_stride as usize,
        )
    }
}

/// The tag byte that opens each record.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum RecordTag {
    BeginStep = 1,
    Frame = 2,
    NoiseProfile = 3,
    BeginDark = 4,
    End = 255,
}

impl RecordTag {
    pub fn from_byte(b: u8) -> Option<Self> {
        Some(match b {
            1 => Self::BeginStep,
            2 => Self::Frame,
            3 => Self::NoiseProfile,
            4 => Self::BeginDark,
            255 => Self::End,
            _ => return None,
        })
    }

    /// Bytes of the record's fixed payload (a Frame's plane follows it).
    const fn fixed_len(self) -> usize {
        match self {
            Self::BeginStep | Self::End => 8,
            Self::Frame => FRAME_FIXED,
            Self::NoiseProfile => 4 + 16 * POSITIONS,
            Self::BeginDark => 0,
        }
    }
}

/// Fixed part of a Frame record: iso, exposure, has_black, black×4, width, height, row stride,
/// pixel stride, data length.
const FRAME_FIXED: usize = 4 + 8 + 1 + 4 * POSITIONS + 5 * 4;

#[derive(Debug, Clone, PartialEq)]
pub enum Record {
    BeginStep { exposure_ns: u64 },
    Frame(RecordedFrame),
    NoiseProfile { iso: u32, profile: NoiseProfile },
    BeginDark,
    End { frames: u64 },
}

impl Record {
    pub fn tag(&self) -> RecordTag {
        match self {
            Self::BeginStep { .. } => RecordTag::BeginStep,
            Self::Frame(_) => RecordTag::Frame,
            Self::NoiseProfile { .. } => RecordTag::NoiseProfile,
            Self::BeginDark => RecordTag::BeginDark,
            Self::End { .. } => RecordTag::End,
        }
    }
}

/// Where a recording stands: its length in bytes (whole records only) and the Frame records in
/// them. A recording cut back to a mark continues with [`RecordingWriter::resume`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct RecordingMark {
    pub bytes: u64,
    pub frames: u64,
}

// ---- encoding --------------------------------------------------------------------------------

fn cfa_code(c: CfaPattern) -> u8 {
    match c {
        CfaPattern::Rggb => 0,
        CfaPattern::Bggr => 1,
        CfaPattern::Grbg => 2,
        CfaPattern::Gbrg => 3,
    }
}

fn cfa_from_code(code: u8) -> Option<CfaPattern> {
    Some(match code {
        0 => CfaPattern::Rggb,
        1 => CfaPattern::Bggr,
        2 => CfaPattern::Grbg,
        3 => CfaPattern::Gbrg,
        _ => return None,
    })
}

/// The exact bytes a recording of `header` starts with (preamble, header, its seal).
pub fn encode_header(header: &RecordingHeader) -> Vec<u8> {
    let mut h = Vec::new();
    let l = &header.layout;
    h.extend_from_slice(&l.width.to_le_bytes());
    h.extend_from_slice(&l.height.to_le_bytes());
    h.push(cfa_code(l.cfa));
    h.extend_from_slice(&l.white.to_le_bytes());
    for b in l.black {
        h.extend_from_slice(&b.to_le_bytes());
    }
    h.extend_from_slice(&header.reference_iso.to_le_bytes());
    h.extend_from_slice(&header.bin_width.to_le_bytes());
    for s in [&header.make, &header.model] {
        let b = s.as_bytes();
        let n = b.len().min(u16::MAX as usize);
        h.extend_from_slice(&(n as u16).to_le_bytes());
        h.extend_from_slice(&b[..n]);
    }
    codec::encode_stream_header(RECORDING_MAGIC, RECORDING_VERSION, &h)
}

fn frame_fixed(meta: &FrameMeta, geometry: [u32; 4], data_len: u32) -> [u8; FRAME_FIXED] {
    let mut p = [0u8; FRAME_FIXED];
    p[0..4].copy_from_slice(&meta.iso.to_le_bytes());
    p[4..12].copy_from_slice(&meta.exposure_ns.to_le_bytes());
    p[12] = meta.black.is_some() as u8;
    for (i, b) in meta.black.unwrap_or([0.0; POSITIONS]).iter().enumerate() {
        p[13 + 4 * i..17 + 4 * i].copy_from_slice(&b.to_le_bytes());
    }
    for (i, v) in geometry.into_iter().chain([data_len]).enumerate() {
        p[29 + 4 * i..33 + 4 * i].copy_from_slice(&v.to_le_bytes());
    }
    p
}

fn noise_profile_payload(iso: u32, profile: &NoiseProfile) -> Vec<u8> {
    let mut p = Vec::with_capacity(RecordTag::NoiseProfile.fixed_len());
    p.extend_from_slice(&iso.to_le_bytes());
    for [s, o] in &profile.0 {
        p.extend_from_slice(&s.to_le_bytes());
        p.extend_from_slice(&o.to_le_bytes());
    }
    p
}

/// Writes a recording record by record (each record is complete when `write_*` returns).
#[derive(Debug)]
pub struct RecordingWriter<W: Write> {
    out: W,
    at: RecordingMark,
}

impl<W: Write> RecordingWriter<W> {
    /// Starts a recording: writes the header.
    pub fn new(mut out: W, header: &RecordingHeader) -> io::Result<Self> {
        let start = encode_header(header);
        out.write_all(&start)?;
        Ok(Self { out, at: RecordingMark { bytes: start.len() as u64, frames: 0 } })
    }

    /// Continues a recording that stood at `mark`: `out` appends right after its first
    /// `mark.bytes` bytes (header and whole records, already in the file). The End record counts
    /// the frames before the mark too.
    pub fn resume(out: W, mark: RecordingMark) -> Self {
        Self { out, at: mark }
    }

    /// Where the recording stands (bytes handed to `out`, flushed or not).
    pub fn mark(&self) -> RecordingMark {
        self.at
    }

    fn record(&mut self, tag: RecordTag, parts: &[&[u8]]) -> io::Result<()> {
        self.at.bytes += codec::write_record(&mut self.out, tag as u8, parts)?;
        Ok(())
    }

    pub fn begin_step(&mut self, exposure_ns: u64) -> io::Result<()> {
        self.record(RecordTag::BeginStep, &[&exposure_ns.to_le_bytes()])
    }

    /// Records the start of a dark (lens-covered) step.
    pub fn begin_dark(&mut self) -> io::Result<()> {
        self.record(RecordTag::BeginDark, &[])
    }

    /// Records a frame exactly as handed over: `data` is the plane's bytes from its start,
    /// `row_stride` and `pixel_stride` in bytes.
    pub fn frame(
        &mut self,
        meta: &FrameMeta,
        width: u32,
        height: u32,
        row_stride: u32,
        pixel_stride: u32,
        data: &[u8],
    ) -> io::Result<()> {
        let len = u32::try_from(data.len()).map_err(|_| {
            io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("a plane of {} bytes does not fit a recording frame record (at most 4 GiB)", data.len()),
            )
        })?;
        let fixed = frame_fixed(meta, [width, height, row_stride, pixel_stride], len);
        self.record(RecordTag::Frame, &[&fixed, data])?;
        self.at.frames += 1;
        Ok(())
    }

    pub fn noise_profile(&mut self, iso: u32, profile: &NoiseProfile) -> io::Result<()> {
        self.record(RecordTag::NoiseProfile, &[&noise_profile_payload(iso, profile)])
    }

    /// Writes the End record (counting every frame of the recording) and returns the writer.
    pub fn finish(mut self) -> io::Result<W> {
        let frames = self.at.frames;
        self.record(RecordTag::End, &[&frames.to_le_bytes()])?;
        self.out.flush()?;
        Ok(self.out)
    }

    pub fn flush(&mut self) -> io::Result<()> {
        self.out.flush()
    }
}

// ---- decoding --------------------------------------------------------------------------------

struct Cursor<'a> {
    b: &'a [u8],
    at: usize,
}

impl<'a> Cursor<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], CodecError> {
        if self.at + n > self.b.len() {
            return Err(CodecError::Invalid { what: WHAT, detail: "header is shorter than its fields".into() });
        }
        let s = &self.b[self.at..self.at + n];
        self.at += n;
        Ok(s)
    }
    fn u16(&mut self) -> Result<u16, CodecError> {
        let s = self.take(2)?;
        Ok(u16::from_le_bytes([s[0], s[1]]))
    }
    fn u32(&mut self) -> Result<u32, CodecError> {
        let s = self.take(4)?;
        Ok(u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
    }
    fn u64(&mut self) -> Result<u64, CodecError> {
        let s = self.take(8)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(s);
        Ok(u64::from_le_bytes(a))
    }
    fn f32(&mut self) -> Result<f32, CodecError> {
        Ok(f32::from_bits(self.u32()?))
    }
    fn f64(&mut self) -> Result<f64, CodecError> {
        Ok(f64::from_bits(self.u64()?))
    }
}

/// The header's fields (the bytes [`codec::open_sealed_header`] returns).
fn decode_header_fields(h: &[u8]) -> Result<RecordingHeader, CodecError> {
    let mut c = Cursor { b: h, at: 0 };
    let width = c.u32()?;
    let height = c.u32()?;
    let code = c.take(1)?[0];
    let cfa = cfa_from_code(code)
        .ok_or_else(|| CodecError::Invalid { what: WHAT, detail: format!("unknown CFA code {code}") })?;
    let white = c.u16()?;
    let black = [c.f32()?, c.f32()?, c.f32()?, c.f32()?];
    let reference_iso = c.u32()?;
    let bin_width = c.u16()?;
    let mut text = || -> Result<String, CodecError> {
        let n = c.u16()? as usize;
        String::from_utf8(c.take(n)?.to_vec())
            .map_err(|_| CodecError::Invalid { what: WHAT, detail: "make/model is not UTF-8".into() })
    };
    let make = text()?;
    let model = text()?;
    let layout = SensorLayout { width, height, cfa, black, white };
    layout.validate().map_err(|e| CodecError::Invalid { what: WHAT, detail: e.to_string() })?;
    // A session sizes its buffers by the header's sensor before any frame arrives: a damaged
    // size is refused here (the limits of a model pack; 268 MP is beyond any camera sensor).
    if width > MAX_SIDE || height > MAX_SIDE || layout.pixels() as u64 > MAX_PIXELS {
        return Err(CodecError::Invalid {
            what: WHAT,
            detail: format!(
                "the header's sensor is {width}×{height}: beyond {MAX_SIDE} pixels a side or {MAX_PIXELS} pixels in all (a damaged header)"
            ),
        });
    }
    Ok(RecordingHeader { layout, reference_iso, bin_width, make, model })
}

/// A record's fixed payload decoded: the whole record, or a Frame still missing its plane.
enum Fixed {
    Whole(Record),
    Frame { meta: FrameMeta, geometry: [u32; 4], data_len: u64 },
}

fn decode_fixed(tag: RecordTag, p: &[u8], index: u64) -> Result<Fixed, CodecError> {
    let mut c = Cursor { b: p, at: 0 };
    Ok(match tag {
        RecordTag::BeginStep => Fixed::Whole(Record::BeginStep { exposure_ns: c.u64()? }),
        RecordTag::End => Fixed::Whole(Record::End { frames: c.u64()? }),
        RecordTag::BeginDark => Fixed::Whole(Record::BeginDark),
        RecordTag::NoiseProfile => {
            let iso = c.u32()?;
            let mut profile = [[0.0; 2]; POSITIONS];
            for so in &mut profile {
                *so = [c.f64()?, c.f64()?];
            }
            Fixed::Whole(Record::NoiseProfile { iso, profile: NoiseProfile(profile) })
        }
        RecordTag::Frame => {
            let iso = c.u32()?;
            let exposure_ns = c.u64()?;
            let has_black = c.take(1)?[0] != 0;
            let black = [c.f32()?, c.f32()?, c.f32()?, c.f32()?];
            let geometry = [c.u32()?, c.u32()?, c.u32()?, c.u32()?];
            let data_len = c.u32()? as u64;
            if data_len > MAX_FRAME_BYTES {
                return Err(CodecError::Invalid {
                    what: WHAT,
                    detail: format!("record {index}: frame of {data_len} bytes"),
                });
            }
            Fixed::Frame { meta: FrameMeta { iso, exposure_ns, black: has_black.then_some(black) }, geometry, data_len }
        }
    })
}

/// Reads a recording record by record.
///
/// Damage is told from an interruption: only a missing tail (the input ends inside a record, or
/// between records without an End record) is an interrupted capture
/// ([`CodecError::CutShort`]). A record whose checksum fails, whose tag is unknown, whose frame
/// length does not fit its own geometry, or which runs past the end of an input that still ends
/// with a whole End record is damage ([`CodecError::Invalid`], naming the record's index and byte
/// offset). The End record's frame count is checked against the frames read, a frame record
/// repeated byte for byte is refused, and nothing may follow the End record: records removed or
/// duplicated with valid checksums are found too.
#[derive(Debug)]
pub struct RecordingReader<R: Read> {
    input: R,
    header: RecordingHeader,
    records: u64,
    ended: bool,
    /// Bytes left in the input when its length is known ([`from_bytes`](Self::from_bytes),
    /// [`new_seekable`](Self::new_seekable)): a length field reaching past them is found before
    /// allocating.
    left: Option<u64>,
    /// Byte offset of the next record in the input.
    offset: u64,
    /// Frame records read so far.
    frames: u64,
    /// Whether the input's last bytes are a whole End record (when its length is known): then a
    /// record running past the end is damage, not an interruption.
    tail_is_end: bool,
    /// Each frame record read (checksum, length and metadata) and its index, to refuse copies.
    seen_frames: HashMap<(u32, u64, u32, u64), u64>,
}

/// Bytes of a whole End record: tag, frame count, seal.
const END_RECORD: usize = 1 + 8 + codec::SEAL;

/// Whether `bytes` ends with a whole End record (tag 255, a frame count, a matching seal).
pub fn ends_with_end_record(bytes: &[u8]) -> bool {
    let Some(at) = bytes.len().checked_sub(END_RECORD) else { return false };
    let r = &bytes[at..];
    if r[0] != RecordTag::End as u8 {
        return false;
    }
    let mut seal = codec::RecordSeal::new(r[0]);
    seal.update(&r[1..9]);
    seal.check(WHAT, [r[9], r[10], r[11], r[12]]).is_ok()
}

/// The plane lengths a frame record of this geometry can hold: from the last sample's end to one
/// spare row past `height` rows. `None` for a geometry no view accepts (such a frame is read and
/// then rejected as a frame, not as damage).
fn plane_len_range(width: u32, height: u32, row_stride: u32, pixel_stride: u32) -> Option<(u64, u64)> {
    let (w, h, rs, ps) = (width as u64, height as u64, row_stride as u64, pixel_stride as u64);
    if w == 0 || h == 0 || ps == 0 || rs < w * ps {
        return None;
    }
    let min = (h - 1) * rs + (w - 1) * ps + 2;
    Some((min, (h + 1) * rs.max(2)))
}

fn read_exact_or<R: Read>(r: &mut R, buf: &mut [u8], context: &str) -> Result<(), CodecError> {
    r.read_exact(buf).map_err(|e| match e.kind() {
        io::ErrorKind::UnexpectedEof => CodecError::CutShort { what: WHAT, context: context.to_string() },
        _ => CodecError::Decode { what: WHAT, detail: e.to_string() },
    })
}

/// Reads until `buf` is full or the input ends; returns the bytes read.
fn read_up_to<R: Read>(r: &mut R, buf: &mut [u8]) -> Result<usize, CodecError> {
    let mut got = 0;
    while got < buf.len() {
        match r.read(&mut buf[got..]) {
            Ok(0) => break,
            Ok(n) => got += n,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(CodecError::Decode { what: WHAT, detail: e.to_string() }),
        }
    }
    Ok(got)
}

fn damaged(index: u64, offset: u64, why: impl std::fmt::Display) -> CodecError {
    CodecError::Invalid { what: WHAT, detail: format!("record {index} at byte {offset} is damaged: {why}") }
}

impl<'a> RecordingReader<&'a [u8]> {
    /// A reader over a whole recording in memory (the fuzzing entry point): the same records and
    /// errors as [`new_seekable`](Self::new_seekable) over the same bytes, and no length field
    /// makes it allocate more than the input holds.
    pub fn from_bytes(bytes: &'a [u8]) -> Result<Self, CodecError> {
        let mut r = Self::new(bytes)?;
        r.left = Some(r.input.len() as u64);
        r.tail_is_end = ends_with_end_record(bytes);
        Ok(r)
    }
}

impl<R: Read + Seek> RecordingReader<R> {
    /// A reader over an input whose length can be learnt (a file): a record running past the end
    /// is told apart from damage as [`from_bytes`](RecordingReader::from_bytes) does, and no
    /// length field makes it allocate more than the input holds.
    pub fn new_seekable(input: R) -> Result<Self, CodecError> {
        let io_err = |e: io::Error| CodecError::Decode { what: WHAT, detail: e.to_string() };
        let mut r = Self::new(input)?;
        let at = r.input.stream_position().map_err(io_err)?;
        let end = r.input.seek(SeekFrom::End(0)).map_err(io_err)?;
        let left = end.saturating_sub(at);
        if left >= END_RECORD as u64 {
            let mut tail = [0u8; END_RECORD];
            r.input.seek(SeekFrom::End(-(END_RECORD as i64))).map_err(io_err)?;
            read_exact_or(&mut r.input, &mut tail, "the End record")?;
            r.tail_is_end = ends_with_end_record(&tail);
        }
        r.input.seek(SeekFrom::Start(at)).map_err(io_err)?;
        r.left = Some(left);
        Ok(r)
    }
}

impl<R: Read> RecordingReader<R> {
    /// A reader over any input, read once from its start. Its length is unknown, so a record
    /// running past the end is taken for an interruption unless its own fields contradict that
    /// (prefer [`new_seekable`](RecordingReader::new_seekable) for a file).
    pub fn new(mut input: R) -> Result<Self, CodecError> {
        let mut start = [0u8; codec::STREAM_START];
        let got = read_up_to(&mut input, &mut start)?;
        let (_, len) = codec::decode_stream_start(
            WHAT,
            RECORDING_MAGIC,
            "NCALREC",
            RECORDING_VERSION..=RECORDING_VERSION,
            &start[..got],
        )?;
        let mut sealed = vec![0u8; len + codec::SEAL];
        read_exact_or(&mut input, &mut sealed, "the header")?;
        let header = decode_header_fields(codec::open_sealed_header(WHAT, &sealed)?)?;
        Ok(Self {
            input,
            header,
            records: 0,
            ended: false,
            left: None,
            offset: (codec::STREAM_START + len + codec::SEAL) as u64,
            frames: 0,
            tail_is_end: false,
            seen_frames: HashMap::new(),
        })
    }

    pub fn header(&self) -> &RecordingHeader {
        &self.header
    }

    /// Whether the End record was read (false for an interrupted capture).
    pub fn ended(&self) -> bool {
        self.ended
    }

    /// Frame records read so far.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    /// The input ends inside the record at `index`, `offset`: an interruption, unless the input
    /// still ends with a whole End record (then the record's length or tag is damaged).
    fn cut_short(&self, index: u64, offset: u64) -> CodecError {
        if self.tail_is_end {
            return damaged(
                index,
                offset,
                "it runs past the end of the file, yet the file ends with a whole End record (a damaged length or tag, not an interrupted capture)",
            );
        }
        CodecError::CutShort { what: WHAT, context: format!("record {index} (at byte {offset})") }
    }

    fn fill(&mut self, buf: &mut [u8], index: u64, offset: u64) -> Result<(), CodecError> {
        if let Some(left) = self.left.as_mut() {
            if (buf.len() as u64) > *left {
                return Err(self.cut_short(index, offset));
            }
            *left -= buf.len() as u64;
        }
        match self.input.read_exact(buf) {
            Ok(()) => Ok(()),
            Err(e) if e.kind() == io::ErrorKind::UnexpectedEof => Err(self.cut_short(index, offset)),
            Err(e) => Err(CodecError::Decode { what: WHAT, detail: e.to_string() }),
        }
    }

    /// The next record; `Ok(None)` at the end (after End, or at a clean end of file).
    pub fn next_record(&mut self) -> Result<Option<Record>, CodecError> {
        if self.ended {
            return Ok(None);
        }
        let mut tag = [0u8; 1];
        if read_up_to(&mut self.input, &mut tag)? == 0 {
            return Ok(None);
        }
        if let Some(left) = self.left.as_mut() {
            *left = left.saturating_sub(1);
        }
        let index = self.records;
        let offset = self.offset;
        let Some(kind) = RecordTag::from_byte(tag[0]) else {
            return Err(damaged(index, offset, format_args!("unknown tag {}", tag[0])));
        };
        let mut seal = codec::RecordSeal::new(tag[0]);
        let mut fixed = vec![0u8; kind.fixed_len()];
        self.fill(&mut fixed, index, offset)?;
        seal.update(&fixed);
        let mut len = 1 + fixed.len() as u64 + codec::SEAL as u64;
        let record = match decode_fixed(kind, &fixed, index)? {
            Fixed::Whole(r) => r,
            Fixed::Frame { meta, geometry: [width, height, row_stride, pixel_stride], data_len } => {
                if let Some((min, max)) = plane_len_range(width, height, row_stride, pixel_stride)
                    && data_len > max
                {
                    return Err(damaged(
                        index,
                        offset,
                        format_args!(
                            "its plane claims {data_len} bytes, but a {width}×{height} frame with row stride {row_stride} and pixel stride {pixel_stride} holds {min}–{max}"
                        ),
                    ));
                }
                if self.left.is_some_and(|left| data_len > left) {
                    return Err(self.cut_short(index, offset));
                }
                let mut data = vec![0u8; data_len as usize];
                self.fill(&mut data, index, offset)?;
                seal.update(&data);
                len += data_len;
                Record::Frame(RecordedFrame { meta, width, height, row_stride, pixel_stride, data })
            }
        };
        let mut stored = [0u8; codec::SEAL];
        self.fill(&mut stored, index, offset)?;
        let crc = seal.value();
        seal.check(WHAT, stored).map_err(|e| damaged(index, offset, format_args!("{} ({})", kind_name(kind), e)))?;
        match &record {
            Record::Frame(f) => {
                let key = (crc, f.data.len() as u64, f.meta.iso, f.meta.exposure_ns);
                if let Some(first) = self.seen_frames.insert(key, index) {
                    return Err(damaged(
                        index,
                        offset,
                        format_args!("it repeats frame record {first} byte for byte (records were duplicated)"),
                    ));
                }
                self.frames += 1;
            }
            Record::End { frames } if *frames != self.frames => {
                return Err(damaged(
                    index,
                    offset,
                    format_args!(
                        "the End record counts {frames} frames but the recording holds {} (frame records were removed or duplicated)",
                        self.frames
                    ),
                ));
            }
            Record::End { .. } => {
                let trailing = match self.left {
                    Some(left) => left,
                    None => read_up_to(&mut self.input, &mut [0u8; 1])? as u64,
                };
                if trailing > 0 {
                    return Err(damaged(
                        index + 1,
                        offset + len,
                        "bytes follow the End record (records were appended or the file was joined to another)",
                    ));
                }
            }
            _ => {}
        }
        self.records += 1;
        self.offset += len;
        self.ended = kind == RecordTag::End;
        Ok(Some(record))
    }
}

fn kind_name(kind: RecordTag) -> &'static str {
    match kind {
        RecordTag::BeginStep => "a BeginStep record",
        RecordTag::Frame => "a Frame record",
        RecordTag::NoiseProfile => "a NoiseProfile record",
        RecordTag::BeginDark => "a BeginDark record",
        RecordTag::End => "the End record",
    }
}

// ---- the app's checkpoint --------------------------------------------------------------------

/// Magic of a [`TeeCheckpoint`] file.
pub const TEE_CHECKPOINT_MAGIC: &[u8; 8] = b"NCALJSES";
/// Version 2: the codec's sealed framing (version 1 had a framing of its own).
pub const TEE_CHECKPOINT_VERSION: u16 = 2;

/// The app's checkpoint of a session that may be teeing into a recording: the session's own
/// checkpoint bytes (`CalibrationSession::checkpoint`) and, when recording, the recording's path
/// and [`RecordingMark`] at that moment, so that session and recording resume in step (the JNI
/// boundary cuts the file back to the mark and continues it with [`RecordingWriter::resume`]).
/// A sealed file of the codec (magic `NCALJSES`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TeeCheckpoint {
    pub recording: Option<(String, RecordingMark)>,
    #[serde(with = "byte_buf")]
    pub session: Vec<u8>,
}

impl TeeCheckpoint {
    const WHAT: &'static str = "session checkpoint";

    pub fn to_bytes(&self) -> Result<Vec<u8>, CodecError> {
        codec::encode(Self::WHAT, TEE_CHECKPOINT_MAGIC, TEE_CHECKPOINT_VERSION, self)
    }

    pub fn from_bytes(bytes: &[u8]) -> Result<Self, CodecError> {
        codec::decode(Self::WHAT, TEE_CHECKPOINT_MAGIC, "NCALJSES", TEE_CHECKPOINT_VERSION, bytes)
    }
}

/// A `Vec<u8>` as one byte string (length, bytes) rather than a sequence of single bytes.
mod byte_buf {
    use serde::{Deserializer, Serializer, de};

    pub(super) fn serialize<S: Serializer>(v: &[u8], s: S) -> Result<S::Ok, S::Error> {
        s.serialize_bytes(v)
    }

    struct Visitor;

    impl de::Visitor<'_> for Visitor {
        type Value = Vec<u8>;

        fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            f.write_str("a byte string")
        }

        fn visit_bytes<E: de::Error>(self, v: &[u8]) -> Result<Vec<u8>, E> {
            Ok(v.to_vec())
        }

        fn visit_byte_buf<E: de::Error>(self, v: Vec<u8>) -> Result<Vec<u8>, E> {
            Ok(v)
        }
    }

    pub(super) fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<u8>, D::Error> {
        d.deserialize_byte_buf(Visitor)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header() -> RecordingHeader {
        RecordingHeader {
            layout: SensorLayout {
                width: 4,
                height: 2,
                cfa: CfaPattern::Gbrg,
                black: [64.0, 64.5, 63.0, 64.0],
                white: 1023,
            },
            reference_iso: 50,
            bin_width: 0,
            make: "Google".into(),
            model: "Pixel 6".into(),
        }
    }

    fn read_all(bytes: &[u8]) -> Result<(RecordingHeader, Vec<Record>, bool), CodecError> {
        let mut r = RecordingReader::from_bytes(bytes)?;
        let mut records = Vec::new();
        while let Some(rec) = r.next_record()? {
            records.push(rec);
        }
        Ok((r.header().clone(), records, r.ended()))
    }

    #[test]
    fn round_trip_and_damage() {
        let mut w = RecordingWriter::new(Vec::new(), &header()).unwrap();
        w.begin_step(1_000_000).unwrap();
        let data: Vec<u8> = (0..20u8).collect();
        let meta = FrameMeta { iso: 50, exposure_ns: 1_000_000, black: Some([64.0, 64.0, 64.0, 65.0]) };
        w.frame(&meta, 4, 2, 12, 2, &data).unwrap();
        w.noise_profile(50, &NoiseProfile([[1e-5, 2e-7]; 4])).unwrap();
        let bytes = w.finish().unwrap();

        let mut r = RecordingReader::new(&bytes[..]).unwrap();
        assert_eq!(r.header(), &header());
        assert_eq!(r.next_record().unwrap(), Some(Record::BeginStep { exposure_ns: 1_000_000 }));
        let Some(Record::Frame(f)) = r.next_record().unwrap() else { panic!("frame expected") };
        assert_eq!(f.meta, meta);
        assert_eq!(f.data, data);
        assert_eq!(f.view().unwrap().row(1)[0], u16::from_le_bytes([12, 13]));
        assert!(matches!(r.next_record().unwrap(), Some(Record::NoiseProfile { iso: 50, .. })));
        assert_eq!(r.next_record().unwrap(), Some(Record::End { frames: 1 }));
        assert!(r.ended());
        assert_eq!(r.next_record().unwrap(), None);

        // Cut inside the frame record: a clear error, not a panic.
        let mut r = RecordingReader::new(&bytes[..bytes.len() - 100]).unwrap();
        r.next_record().unwrap();
        let e = r.next_record().unwrap_err();
        assert!(e.to_string().contains("cut short"), "{e}");
        // A flipped data byte fails its checksum.
        let mut bad = bytes.clone();
        let n = bad.len();
        bad[n - 90] ^= 1;
        let mut r = RecordingReader::new(&bad[..]).unwrap();
        let mut err = None;
        while err.is_none() {
            match r.next_record() {
                Ok(Some(_)) => {}
                Ok(None) => break,
                Err(e) => err = Some(e),
            }
        }
        let err = err.expect("an error").to_string();
        assert!(err.contains("record 1 at byte 81 is damaged") && err.contains("checksum"), "{err}");
        assert!(matches!(RecordingReader::new(&b"NCALPACK...."[..]), Err(CodecError::BadMagic { .. })));
        assert!(matches!(RecordingReader::new(&bytes[..12]), Err(CodecError::Truncated { .. })));
        assert!(matches!(RecordingReader::new(&bytes[..20]), Err(CodecError::CutShort { .. })));
    }

    /// Bytes written by the recording writer before it became a codec over `codec`'s framing:
    /// recordings on disk must keep reading, and new ones must be byte-identical.
    const GOLDEN: &str = "4e43414c5245430001002b000000040000000200000002ff0f000080420000814200007c420000804237000000080005004dc3a46b6501004d973130e80187d6120000000000c119812e023700000087d6120000000000000000000000000000000000000000000004000000020000000c0000000200000014000000000102030405060708090a0b0c0d0e0f101112138a81eed3026e000000436b09000000000001000080420080804200007e420000804204000000020000000c0000000200000014000000000102030405060708090a0b0c0d0e0f10111213c9443961036e000000f168e388b5f8e43e48afbc9af2d78a3e691d554d1075ef3e48afbc9af2d78a3ef168e388b5f8e43e76830df4f521943ef168e388b5f8e43e8dedb5a0f7c6903e5eaa4d07ff0200000000000000981f63ed";

    fn golden_header() -> RecordingHeader {
        RecordingHeader {
            layout: SensorLayout {
                width: 4,
                height: 2,
                cfa: CfaPattern::Grbg,
                black: [64.0, 64.5, 63.0, 64.0],
                white: 4095,
            },
            reference_iso: 55,
            bin_width: 8,
            make: "Mäke".into(),
            model: "M".into(),
        }
    }

    const PROFILE: NoiseProfile = NoiseProfile([[1e-5, 2e-7], [1.5e-5, 2e-7], [1e-5, 3e-7], [1e-5, 2.5e-7]]);

    /// Writes the golden recording, continuing from a resume after the first `resume_after`
    /// records (0: one writer throughout).
    fn golden_bytes(resume_after: usize) -> Vec<u8> {
        let data: Vec<u8> = (0..20u8).collect();
        let second = FrameMeta { iso: 110, exposure_ns: 617_283, black: Some([64.0, 64.25, 63.5, 64.0]) };
        type Step<'a> = Box<dyn Fn(&mut RecordingWriter<Vec<u8>>) -> io::Result<()> + 'a>;
        let steps: Vec<Step<'_>> = vec![
            Box::new(|w| w.begin_step(1_234_567)),
            Box::new(|w| w.frame(&FrameMeta::new(55, 1_234_567), 4, 2, 12, 2, &data)),
            Box::new(|w| w.frame(&second, 4, 2, 12, 2, &data)),
            Box::new(|w| w.noise_profile(110, &PROFILE)),
        ];
        let mut w = RecordingWriter::new(Vec::new(), &golden_header()).unwrap();
        for (i, step) in steps.iter().enumerate() {
            if resume_after > 0 && i == resume_after {
                let mark = w.mark();
                let mut file = w.finish().unwrap();
                file.truncate(mark.bytes as usize);
                w = RecordingWriter::resume(file, mark);
            }
            step(&mut w).unwrap();
        }
        w.finish().unwrap()
    }

    #[test]
    fn bytes_are_the_format_of_record() {
        let want: Vec<u8> =
            (0..GOLDEN.len()).step_by(2).map(|i| u8::from_str_radix(&GOLDEN[i..i + 2], 16).unwrap()).collect();
        assert_eq!(golden_bytes(0), want);
        // Resumed after every possible record: the same file.
        for k in 1..4 {
            assert_eq!(golden_bytes(k), want, "resumed after {k} records");
        }
        assert_eq!(encode_header(&golden_header())[..], want[..61]);
        let (h, records, ended) = read_all(&want).unwrap();
        assert_eq!(h, golden_header());
        assert!(ended);
        let tags: Vec<RecordTag> = records.iter().map(Record::tag).collect();
        use RecordTag::*;
        assert_eq!(tags, [BeginStep, Frame, Frame, NoiseProfile, End]);
        assert_eq!(records[3], Record::NoiseProfile { iso: 110, profile: PROFILE });
        assert_eq!(records[4], Record::End { frames: 2 });
        for t in [BeginStep, Frame, NoiseProfile, BeginDark, End] {
            assert_eq!(RecordTag::from_byte(t as u8), Some(t));
        }
        assert_eq!(RecordTag::from_byte(5), None);
    }

    /// A BeginDark record: one tag byte and its checksum, read back as written.
    #[test]
    fn begin_dark_round_trips() {
        let mut w = RecordingWriter::new(Vec::new(), &golden_header()).unwrap();
        w.begin_step(1_000_000).unwrap();
        w.begin_dark().unwrap();
        let bytes = w.finish().unwrap();
        let (_, records, ended) = read_all(&bytes).unwrap();
        assert!(ended);
        assert_eq!(records[..2], [Record::BeginStep { exposure_ns: 1_000_000 }, Record::BeginDark]);
        // Tag 4 then the CRC of the tag alone, right after the 13-byte BeginStep record.
        assert_eq!(bytes[61 + 13], 4);
        assert_eq!(bytes[61 + 14..61 + 18], crc32fast::hash(&[4]).to_le_bytes());
    }

    #[test]
    fn byte_reader_refuses_damage_without_panicking() {
        let good = golden_bytes(0);
        // Every prefix: a header error, or whole records then a cut (or a clean end between records).
        for n in 0..good.len() {
            match read_all(&good[..n]) {
                Ok((_, records, ended)) => assert!(!ended && records.len() < 5, "prefix {n}"),
                Err(e) => assert!(
                    matches!(
                        e,
                        CodecError::CutShort { .. } | CodecError::Truncated { .. } | CodecError::BadMagic { .. }
                    ),
                    "prefix {n}: {e}"
                ),
            }
        }
        // A frame claiming 2 GiB is refused before any allocation of that size: its geometry
        // holds 20–36 bytes.
        let frame_at = 61 + 13; // header 14 + 43 + 4, BeginStep 1 + 8 + 4
        let mut huge = good.clone();
        huge[frame_at + 1 + 45..frame_at + 1 + 49].copy_from_slice(&(1u32 << 31).to_le_bytes());
        let mut r = RecordingReader::from_bytes(&huge).unwrap();
        r.next_record().unwrap();
        assert!(matches!(r.next_record(), Err(CodecError::Invalid { .. })));
        huge[frame_at + 1 + 45..frame_at + 1 + 49].copy_from_slice(&u32::MAX.to_le_bytes());
        let mut r = RecordingReader::from_bytes(&huge).unwrap();
        r.next_record().unwrap();
        assert!(matches!(r.next_record(), Err(CodecError::Invalid { .. })));
        // Every single flipped bit is caught (a seal, a magic, a version, or a field check).
        for i in 0..good.len() {
            let mut bad = good.clone();
            bad[i] ^= 0x10;
            assert!(read_all(&bad).map(|(_, r, _)| r) != Ok(read_all(&good).unwrap().1), "flip at {i} went unnoticed");
        }
    }

    /// A recording of `n` frames of 4×2 (row stride 12, planes of 20 bytes, 1 + 49 + 20 + 4 = 74
    /// bytes a record) after one BeginStep; returns it and each frame record's offset.
    fn frames_recording(n: u64) -> (Vec<u8>, Vec<usize>) {
        let mut w = RecordingWriter::new(Vec::new(), &header()).unwrap();
        w.begin_step(1_000_000).unwrap();
        let mut at = Vec::new();
        for i in 0..n {
            at.push(w.mark().bytes as usize);
            let data: Vec<u8> = (0..20u8).map(|b| b.wrapping_mul(i as u8 + 3)).collect();
            w.frame(&FrameMeta::new(50 + i as u32, 1_000_000), 4, 2, 12, 2, &data).unwrap();
        }
        (w.finish().unwrap(), at)
    }

    /// Every record through all three readers: the byte reader, the seekable reader and the plain
    /// stream reader.
    fn read_three(bytes: &[u8]) -> [Result<(u64, bool), CodecError>; 3] {
        fn drain<R: Read>(mut r: RecordingReader<R>) -> Result<(u64, bool), CodecError> {
            while r.next_record()?.is_some() {}
            Ok((r.frames(), r.ended()))
        }
        [
            RecordingReader::from_bytes(bytes).and_then(drain),
            RecordingReader::new_seekable(io::Cursor::new(bytes)).and_then(drain),
            RecordingReader::new(bytes).and_then(drain),
        ]
    }

    fn frame_len_field(at: usize) -> std::ops::Range<usize> {
        at + 1 + 45..at + 1 + 49
    }

    /// One flipped bit in a middle record's length is damage named by record
    /// and offset, not "an interrupted capture".
    #[test]
    fn a_damaged_length_is_not_an_interruption() {
        let (good, at) = frames_recording(6);
        for r in read_three(&good) {
            assert_eq!(r, Ok((6, true)));
        }
        // 20 → 20 + 2^20: runs past the end of the file; every reader calls it damage.
        for (k, bit) in [(2usize, 20u32), (0, 24), (5, 20), (5, 3)] {
            let mut bad = good.clone();
            let f = frame_len_field(at[k]);
            let len = u32::from_le_bytes(bad[f.clone()].try_into().unwrap()) ^ (1 << bit);
            bad[f].copy_from_slice(&len.to_le_bytes());
            for (i, r) in read_three(&bad).into_iter().enumerate() {
                let e = r.expect_err("damage");
                let want = format!("record {} at byte {} is damaged", k + 1, at[k]);
                assert!(matches!(e, CodecError::Invalid { .. }), "reader {i}, frame {k}, bit {bit}: {e}");
                assert!(e.to_string().contains(&want), "reader {i}: {e}");
            }
        }
        // 20 → 28: still within its geometry's 20–36 bytes, on the last frame: it runs past the
        // end, but the file ends with a whole End record, so the readers that know the length
        // call it damage (the stream reader finds the bad checksum).
        let mut bad = good.clone();
        let f = frame_len_field(at[5]);
        bad[f].copy_from_slice(&28u32.to_le_bytes());
        for (i, r) in read_three(&bad).into_iter().enumerate() {
            let e = r.expect_err("damage");
            assert!(e.to_string().contains(&format!("record 6 at byte {} is damaged", at[5])), "reader {i}: {e}");
        }
        // A real interruption: the file cut inside the last frame record.
        for cut in [at[5] + 30, at[5] + 1, good.len() - 1] {
            for (i, r) in read_three(&good[..cut]).into_iter().enumerate() {
                assert!(matches!(r, Err(CodecError::CutShort { .. })), "reader {i}, cut {cut}: {r:?}");
            }
        }
        // Cut between records: whole records, no End.
        for r in read_three(&good[..at[5]]) {
            assert_eq!(r, Ok((5, false)));
        }
    }

    /// A header claiming a sensor no camera has is refused before a session sizes buffers by it.
    #[test]
    fn absurd_sensor_sizes_are_refused_in_the_header() {
        for (w, h) in [(u32::MAX, u32::MAX), (100_000, 100_000), (65_536, 65_536), (70_000, 2)] {
            let mut hd = header();
            hd.layout.width = w;
            hd.layout.height = h;
            let e = RecordingReader::from_bytes(&encode_header(&hd)).unwrap_err();
            assert!(e.to_string().contains("a damaged header"), "{w}×{h}: {e}");
        }
        let mut hd = header();
        (hd.layout.width, hd.layout.height) = (16_384, 12_288);
        RecordingReader::from_bytes(&encode_header(&hd)).expect("a 201 MP sensor is read");
    }

    /// Records removed or duplicated, each with a valid checksum, are damage, not a good recording.
    #[test]
    fn removed_and_duplicated_records_are_found() {
        let (good, at) = frames_recording(5);
        let rec = 74;
        // Frame 2 removed.
        let mut removed = good[..at[2]].to_vec();
        removed.extend_from_slice(&good[at[2] + rec..]);
        for (i, r) in read_three(&removed).into_iter().enumerate() {
            let e = r.expect_err("a removed frame");
            assert!(e.to_string().contains("End record counts 5 frames but the recording holds 4"), "reader {i}: {e}");
        }
        // Frame 2 duplicated.
        let mut dup = good[..at[3]].to_vec();
        dup.extend_from_slice(&good[at[2]..]);
        for (i, r) in read_three(&dup).into_iter().enumerate() {
            let e = r.expect_err("a duplicated frame");
            assert!(e.to_string().contains("repeats frame record 3"), "reader {i}: {e}");
            assert!(e.to_string().contains(&format!("record 4 at byte {}", at[3])), "reader {i}: {e}");
        }
        // Frame 2 duplicated and frame 4 removed: the count matches, the copy is still found.
        let mut swapped = good[..at[3]].to_vec();
        swapped.extend_from_slice(&good[at[2]..at[4]]);
        swapped.extend_from_slice(&good[at[4] + rec..]);
        for r in read_three(&swapped) {
            assert!(r.expect_err("a copy").to_string().contains("repeats frame record"));
        }
        // A recording joined to another: bytes after the End record.
        let mut joined = good.clone();
        joined.extend_from_slice(&good[at[0]..at[1]]);
        for (i, r) in read_three(&joined).into_iter().enumerate() {
            let e = r.expect_err("trailing records");
            assert!(e.to_string().contains("bytes follow the End record"), "reader {i}: {e}");
        }
        // The End record removed: an interrupted capture (only a missing tail is one).
        for r in read_three(&good[..good.len() - END_RECORD]) {
            assert_eq!(r, Ok((5, false)));
        }
        assert!(ends_with_end_record(&good) && !ends_with_end_record(&good[..good.len() - 1]));
    }

    #[test]
    fn tee_checkpoints_round_trip_and_are_sealed() {
        let c = TeeCheckpoint {
            recording: Some(("/data/s.rec".into(), RecordingMark { bytes: 12345, frames: 7 })),
            session: (0..=255u8).cycle().take(3000).collect(),
        };
        let b = c.to_bytes().unwrap();
        assert_eq!(&b[..8], TEE_CHECKPOINT_MAGIC);
        assert!(b.len() < 3000 + 64, "the session bytes are stored as one byte string: {}", b.len());
        assert_eq!(TeeCheckpoint::from_bytes(&b).unwrap(), c);
        let none = TeeCheckpoint { recording: None, session: vec![1, 2, 3] };
        assert_eq!(TeeCheckpoint::from_bytes(&none.to_bytes().unwrap()).unwrap(), none);
        let mut bad = b.clone();
        let last = bad.len() - 1;
        bad[last] ^= 1;
        assert!(matches!(TeeCheckpoint::from_bytes(&bad), Err(CodecError::Checksum { .. })));
        let mut v1 = b;
        v1[8] = 1;
        assert!(matches!(TeeCheckpoint::from_bytes(&v1), Err(CodecError::OlderVersion { .. })));
    }
}
