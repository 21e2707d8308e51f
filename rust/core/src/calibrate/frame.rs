//! Stride-aware views over raw frames: Camera2 planes (bytes with padded rows) are read in place.

use std::borrow::Cow;

use crate::error::FrameError;

/// Where a frame's samples live.
#[derive(Debug, Clone, Copy)]
enum Samples<'a> {
    /// Native `u16` samples; `row_stride` in samples.
    U16(&'a [u16]),
    /// Little-endian 16-bit samples as bytes (a Camera2 `ByteBuffer`); `row_stride` in bytes.
    LeBytes(&'a [u8]),
}

/// A borrowed `width × height` frame of 16-bit raw samples with a row stride.
#[derive(Debug, Clone, Copy)]
pub struct FrameView<'a> {
    samples: Samples<'a>,
    width: usize,
    height: usize,
    row_stride: usize,
}

impl<'a> FrameView<'a> {
    /// A view over `u16` samples; `row_stride` counts samples (≥ width).
    pub fn from_u16(data: &'a [u16], width: usize, height: usize, row_stride: usize) -> Result<Self, FrameError> {
        check_dims(width, height)?;
        if row_stride < width {
            return Err(FrameError::RowStride { row_stride: row_stride * 2, min: width * 2 });
        }
        let needed = (height - 1) * row_stride + width;
        if data.len() < needed {
            return Err(FrameError::TooShort {
                len: data.len() * 2,
                needed: needed * 2,
                width,
                height,
                row_stride: row_stride * 2,
            });
        }
        Ok(Self { samples: Samples::U16(data), width, height, row_stride })
    }

    /// A view over a Camera2 `RAW_SENSOR` plane: little-endian 16-bit samples, `row_stride` in
    /// bytes, `pixel_stride` in bytes (must be 2). The buffer must hold at least
    /// `(height − 1) · row_stride + 2 · width` bytes; the last row need not be padded.
    pub fn from_le_bytes(
        data: &'a [u8],
        width: usize,
        height: usize,
        row_stride: usize,
        pixel_stride: usize,
    ) -> Result<Self, FrameError> {
        check_dims(width, height)?;
        if pixel_stride != 2 {
            return Err(FrameError::PixelStride { pixel_stride });
        }
        if row_stride < width * 2 {
            return Err(FrameError::RowStride { row_stride, min: width * 2 });
        }
        let needed = (height - 1) * row_stride + 2 * width;
        if data.len() < needed {
            return Err(FrameError::TooShort { len: data.len(), needed, width, height, row_stride });
        }
        Ok(Self { samples: Samples::LeBytes(data), width, height, row_stride })
    }

    /// A view over a standard-layout (row-major, contiguous) ndarray image.
    pub fn from_array<S: ndarray::Data<Elem = u16>>(
        a: &'a ndarray::ArrayBase<S, ndarray::Ix2>,
    ) -> Result<Self, FrameError> {
        let (h, w) = a.dim();
        let s = a.as_slice().ok_or(FrameError::RowStride { row_stride: 0, min: w * 2 })?;
        Self::from_u16(s, w, h, w)
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    /// Checks the frame has the expected size.
    pub fn expect_size(&self, width: usize, height: usize) -> Result<(), FrameError> {
        if self.width != width || self.height != height {
            return Err(FrameError::SizeMismatch {
                width: self.width,
                height: self.height,
                expected_width: width,
                expected_height: height,
            });
        }
        Ok(())
    }

    /// Row `y` as `u16` samples: borrowed when the memory allows it (native samples, or aligned
    /// little-endian bytes on a little-endian target), otherwise decoded into a fresh row.
    #[inline]
    pub fn row(&self, y: usize) -> Cow<'a, [u16]> {
        match self.samples {
            Samples::U16(d) => {
                let start = y * self.row_stride;
                Cow::Borrowed(&d[start..start + self.width])
            }
            Samples::LeBytes(d) => {
                let start = y * self.row_stride;
                let bytes = &d[start..start + 2 * self.width];
                if cfg!(target_endian = "little")
                    && let Ok(s) = bytemuck::try_cast_slice::<u8, u16>(bytes)
                {
                    return Cow::Borrowed(s);
                }
                Cow::Owned(bytes.chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]])).collect())
            }
        }
    }

    /// The sample at row `y`, column `x` (both in range).
    #[inline]
    pub fn get(&self, y: usize, x: usize) -> u16 {
        match self.samples {
            Samples::U16(d) => d[y * self.row_stride + x],
            Samples::LeBytes(d) => {
                let i = y * self.row_stride + 2 * x;
                u16::from_le_bytes([d[i], d[i + 1]])
            }
        }
    }

    /// Reads row `y` into `out` (length ≥ width) without allocating.
    #[inline]
    pub fn read_row(&self, y: usize, out: &mut [u16]) {
        match self.row(y) {
            Cow::Borrowed(s) => out[..self.width].copy_from_slice(s),
            Cow::Owned(v) => out[..self.width].copy_from_slice(&v),
        }
    }

    /// Copies the frame into a dense row-major array (for whole-image work; never on the
    /// calibration path).
    pub fn to_array(&self) -> ndarray::Array2<u16> {
        let mut v = Vec::with_capacity(self.width * self.height);
        for y in 0..self.height {
            v.extend_from_slice(&self.row(y));
        }
        ndarray::Array2::from_shape_vec((self.height, self.width), v)
            .expect("rows of width samples fill a height × width array")
    }
}

fn check_dims(width: usize, height: usize) -> Result<(), FrameError> {
    if width == 0 || height == 0 {
        return Err(FrameError::Empty { width, height });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn padded_le_rows_read_in_place() {
        let (w, h, stride) = (3usize, 2usize, 10usize);
        let mut bytes = vec![0xEEu8; stride * (h - 1) + 2 * w];
        for y in 0..h {
            for x in 0..w {
                let v = (y * 100 + x) as u16;
                bytes[y * stride + 2 * x..y * stride + 2 * x + 2].copy_from_slice(&v.to_le_bytes());
            }
        }
        let f = FrameView::from_le_bytes(&bytes, w, h, stride, 2).unwrap();
        assert_eq!(&*f.row(1), &[100, 101, 102]);
        let a = f.to_array();
        assert_eq!(a[[1, 2]], 102);
        assert_eq!(a[[0, 1]], 1);
        // Misaligned start still decodes.
        let mut shifted = vec![0u8; 1];
        shifted.extend_from_slice(&bytes);
        let f = FrameView::from_le_bytes(&shifted[1..], w, h, stride, 2).unwrap();
        assert_eq!(&*f.row(1), &[100, 101, 102]);
    }

    #[test]
    fn bad_buffers_are_named() {
        let bytes = vec![0u8; 10];
        assert!(matches!(FrameView::from_le_bytes(&bytes, 4, 2, 8, 1), Err(FrameError::PixelStride { .. })));
        assert!(matches!(FrameView::from_le_bytes(&bytes, 4, 2, 6, 2), Err(FrameError::RowStride { .. })));
        let e = FrameView::from_le_bytes(&bytes, 4, 2, 8, 2).unwrap_err();
        assert!(e.to_string().contains("(height − 1) · rowStride + 2 · width"), "{e}");
        assert!(FrameView::from_le_bytes(&bytes[..8], 4, 2, 8, 2).is_err());
        assert!(FrameView::from_le_bytes(&[0u8; 16], 4, 2, 8, 2).is_ok());
    }
}
