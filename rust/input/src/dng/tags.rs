//! TIFF / DNG tags by name: the [`Tag`] enum of every tag noisecal reads or writes (TIFF 6,
//! TIFF/EP, EXIF 2.3, DNG 1.6), with [`Tag::Unknown`] for the others, so no tag number appears
//! anywhere else in the code.
//!
//! The list below is the only place tag numbers are written. It also generates the
//! SCREAMING_CASE constants of [`tag`] (e.g. `tag::CFA_PATTERN`), aliases of the variants named
//! as the specifications' tables name them, which the TIFF fixtures use.

use std::cmp::Ordering;
use std::fmt;
use std::hash::{Hash, Hasher};

macro_rules! tags {
    ($( $(#[$doc:meta])* $variant:ident = $value:literal, $name:literal, $konst:ident; )*) => {
        /// A TIFF tag. Equality, ordering and hashing follow the tag number, so
        /// `Tag::Unknown(33422) == Tag::CfaPattern` and a map of tags is in file order (TIFF
        /// requires IFD entries sorted by number).
        #[derive(Debug, Clone, Copy)]
        pub enum Tag {
            $( $(#[$doc])* $variant, )*
            /// Any other tag, by number.
            Unknown(u16),
        }

        impl Tag {
            /// Every named tag, in ascending number.
            pub const ALL: &'static [Tag] = &[$( Tag::$variant, )*];

            /// The tag with number `n`: a named variant when noisecal knows it, else
            /// [`Tag::Unknown`].
            pub const fn from_u16(n: u16) -> Tag {
                match n {
                    $( $value => Tag::$variant, )*
                    _ => Tag::Unknown(n),
                }
            }

            /// The tag's number.
            pub const fn to_u16(self) -> u16 {
                match self {
                    $( Tag::$variant => $value, )*
                    Tag::Unknown(n) => n,
                }
            }

            /// The name the specification gives the tag (`None` for an unknown tag).
            pub const fn name(self) -> Option<&'static str> {
                match self.normalized() {
                    $( Tag::$variant => Some($name), )*
                    Tag::Unknown(_) => None,
                }
            }
        }

        /// The tags under the names of the specifications' tables (`tag::CFA_PATTERN` is
        /// [`Tag::CfaPattern`]).
        pub mod tag {
            use super::Tag;
            $( #[doc = concat!("[`Tag::", stringify!($variant), "`] (", stringify!($value), ").")]
               pub const $konst: Tag = Tag::$variant; )*
        }
    };
}

tags! {
    /// 0 for the main image, 1 for a reduced-resolution preview.
    NewSubfileType = 254, "NewSubfileType", NEW_SUBFILE_TYPE;
    ImageWidth = 256, "ImageWidth", IMAGE_WIDTH;
    ImageLength = 257, "ImageLength", IMAGE_LENGTH;
    BitsPerSample = 258, "BitsPerSample", BITS_PER_SAMPLE;
    Compression = 259, "Compression", COMPRESSION;
    /// 32803 for a CFA mosaic, 34892 for demosaiced `LinearRaw` data.
    PhotometricInterpretation = 262, "PhotometricInterpretation", PHOTOMETRIC;
    Make = 271, "Make", MAKE;
    Model = 272, "Model", MODEL;
    StripOffsets = 273, "StripOffsets", STRIP_OFFSETS;
    Orientation = 274, "Orientation", ORIENTATION;
    SamplesPerPixel = 277, "SamplesPerPixel", SAMPLES_PER_PIXEL;
    RowsPerStrip = 278, "RowsPerStrip", ROWS_PER_STRIP;
    StripByteCounts = 279, "StripByteCounts", STRIP_BYTE_COUNTS;
    PlanarConfiguration = 284, "PlanarConfiguration", PLANAR_CONFIGURATION;
    Software = 305, "Software", SOFTWARE;
    Predictor = 317, "Predictor", PREDICTOR;
    TileWidth = 322, "TileWidth", TILE_WIDTH;
    TileLength = 323, "TileLength", TILE_LENGTH;
    TileOffsets = 324, "TileOffsets", TILE_OFFSETS;
    TileByteCounts = 325, "TileByteCounts", TILE_BYTE_COUNTS;
    /// Pointer to child IFDs (the raw image of a DNG whose IFD0 is a preview).
    SubIfds = 330, "SubIFDs", SUB_IFDS;
    SampleFormat = 339, "SampleFormat", SAMPLE_FORMAT;
    JpegTables = 347, "JPEGTables", JPEG_TABLES;
    CfaRepeatPatternDim = 33421, "CFARepeatPatternDim", CFA_REPEAT_PATTERN_DIM;
    CfaPattern = 33422, "CFAPattern", CFA_PATTERN;
    ExposureTime = 33434, "ExposureTime", EXPOSURE_TIME;
    /// Pointer to the EXIF IFD.
    ExifIfd = 34665, "ExifIFD", EXIF_IFD;
    /// `PhotographicSensitivity` in EXIF 2.3; 65535 means "65535 or more".
    IsoSpeedRatings = 34855, "ISOSpeedRatings", ISO_SPEED_RATINGS;
    SensitivityType = 34864, "SensitivityType", SENSITIVITY_TYPE;
    StandardOutputSensitivity = 34865, "StandardOutputSensitivity", STANDARD_OUTPUT_SENSITIVITY;
    RecommendedExposureIndex = 34866, "RecommendedExposureIndex", RECOMMENDED_EXPOSURE_INDEX;
    IsoSpeed = 34867, "ISOSpeed", ISO_SPEED;
    ExifVersion = 36864, "ExifVersion", EXIF_VERSION;
    DngVersion = 50706, "DNGVersion", DNG_VERSION;
    DngBackwardVersion = 50707, "DNGBackwardVersion", DNG_BACKWARD_VERSION;
    UniqueCameraModel = 50708, "UniqueCameraModel", UNIQUE_CAMERA_MODEL;
    CfaPlaneColor = 50710, "CFAPlaneColor", CFA_PLANE_COLOR;
    CfaLayout = 50711, "CFALayout", CFA_LAYOUT;
    /// Maps stored values to linear ones; decoders apply it, so a rewritten raw image drops it.
    LinearizationTable = 50712, "LinearizationTable", LINEARIZATION_TABLE;
    BlackLevelRepeatDim = 50713, "BlackLevelRepeatDim", BLACK_LEVEL_REPEAT_DIM;
    BlackLevel = 50714, "BlackLevel", BLACK_LEVEL;
    BlackLevelDeltaH = 50715, "BlackLevelDeltaH", BLACK_LEVEL_DELTA_H;
    BlackLevelDeltaV = 50716, "BlackLevelDeltaV", BLACK_LEVEL_DELTA_V;
    WhiteLevel = 50717, "WhiteLevel", WHITE_LEVEL;
    ColorMatrix1 = 50721, "ColorMatrix1", COLOR_MATRIX_1;
    AsShotNeutral = 50728, "AsShotNeutral", AS_SHOT_NEUTRAL;
    CalibrationIlluminant1 = 50778, "CalibrationIlluminant1", CALIBRATION_ILLUMINANT_1;
    /// 16 bytes naming the raw data (raw converters key their caches on it).
    RawDataUniqueId = 50781, "RawDataUniqueID", RAW_DATA_UNIQUE_ID;
    ActiveArea = 50829, "ActiveArea", ACTIVE_AREA;
    /// MD5 of the raw image data (DNG 1.2); a file with other pixels must not carry it.
    RawImageDigest = 50972, "RawImageDigest", RAW_IMAGE_DIGEST;
    RowInterleaveFactor = 50975, "RowInterleaveFactor", ROW_INTERLEAVE_FACTOR;
    /// `(S, O)` pairs per colour plane: variance = S·signal + O.
    NoiseProfile = 51041, "NoiseProfile", NOISE_PROFILE;
    /// MD5 of the raw image data (DNG 1.4); a file with other pixels must not carry it.
    NewRawImageDigest = 51111, "NewRawImageDigest", NEW_RAW_IMAGE_DIGEST;
    ColumnInterleaveFactor = 52547, "ColumnInterleaveFactor", COLUMN_INTERLEAVE_FACTOR;
    JxlDistance = 52553, "JXLDistance", JXL_DISTANCE;
    JxlEffort = 52554, "JXLEffort", JXL_EFFORT;
    JxlDecodeSpeed = 52555, "JXLDecodeSpeed", JXL_DECODE_SPEED;
}

impl Tag {
    /// The named variant for an `Unknown` number noisecal knows.
    const fn normalized(self) -> Tag {
        Tag::from_u16(self.to_u16())
    }
}

impl From<u16> for Tag {
    fn from(n: u16) -> Tag {
        Tag::from_u16(n)
    }
}

impl From<Tag> for u16 {
    fn from(t: Tag) -> u16 {
        t.to_u16()
    }
}

impl PartialEq for Tag {
    fn eq(&self, other: &Tag) -> bool {
        self.to_u16() == other.to_u16()
    }
}

impl Eq for Tag {}

impl Hash for Tag {
    fn hash<H: Hasher>(&self, state: &mut H) {
        self.to_u16().hash(state);
    }
}

impl PartialOrd for Tag {
    fn partial_cmp(&self, other: &Tag) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Tag {
    fn cmp(&self, other: &Tag) -> Ordering {
        self.to_u16().cmp(&other.to_u16())
    }
}

/// `CFAPattern (33422)`; an unknown tag shows its number only.
impl fmt::Display for Tag {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.name() {
            Some(name) => write!(f, "{name} ({})", self.to_u16()),
            None => write!(f, "{}", self.to_u16()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::{BTreeMap, HashSet};

    #[test]
    fn numbers_round_trip_and_unknowns_fall_back() {
        let mut seen = HashSet::new();
        for &t in Tag::ALL {
            let n = t.to_u16();
            assert!(seen.insert(n), "{t:?} reuses number {n}");
            let back = Tag::from_u16(n);
            assert!(!matches!(back, Tag::Unknown(_)) && back.name().is_some() && back.name() == t.name(), "{t:?}");
            assert_eq!(u16::from(Tag::from(n)), n);
        }
        assert!(Tag::ALL.windows(2).all(|w| w[0] < w[1]), "ALL is in ascending number");
        assert_eq!(Tag::ALL.len(), 57);
        assert_eq!(Tag::CfaPattern.to_u16(), 33422);
        assert_eq!(Tag::SubIfds.to_u16(), 330);
        assert_eq!(tag::EXIF_IFD.to_u16(), 34665);
        assert!(matches!(Tag::from_u16(51041), Tag::NoiseProfile));
        assert!(matches!(Tag::from_u16(50712), Tag::LinearizationTable));
        assert!(matches!(Tag::from_u16(50719), Tag::Unknown(50719)));
        assert!(matches!(Tag::from_u16(0), Tag::Unknown(0)));
        assert_eq!(Tag::Unknown(42).name(), None);
    }

    #[test]
    fn identity_and_order_follow_the_number() {
        assert_eq!(Tag::Unknown(33422), Tag::CfaPattern);
        assert_eq!(Tag::Unknown(33422).name(), Some("CFAPattern"));
        assert_ne!(Tag::Unknown(33423), Tag::CfaPattern);
        let mut m = BTreeMap::new();
        m.insert(Tag::NoiseProfile, 3);
        m.insert(Tag::Unknown(300), 2);
        m.insert(Tag::ImageWidth, 1);
        m.insert(Tag::Unknown(256), 4);
        let order: Vec<(u16, i32)> = m.iter().map(|(t, v)| (t.to_u16(), *v)).collect();
        assert_eq!(order, [(256, 4), (300, 2), (51041, 3)]);
        assert_eq!(Tag::CfaPattern.to_string(), "CFAPattern (33422)");
        assert_eq!(Tag::Unknown(7).to_string(), "7");
    }
}
