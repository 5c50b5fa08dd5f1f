//! The versioned weight-blob format (docs/spec.md section 10): how a trained actor travels from the
//! ground to the flight computer.
//!
//! Byte layout (all integers little-endian):
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 4 | magic `LTGB` |
//! | 4 | 2 | format version ([`FORMAT_VERSION`]) |
//! | 6 | 4 | payload length L |
//! | 10 | L | payload: postcard encoding of [`NetworkBlob`] |
//! | 10 + L | 4 | CRC-32 (ISO-HDLC, the zlib/PNG one) of the payload |
//!
//! Decoding borrows: every weight array in a decoded [`NetworkBlob`] is a slice of the input
//! bytes, so a blob linked into flash is used in place, never copied to RAM.
//!
//! Every layer's weight array starts at a multiple of [`WEIGHT_ALIGN`] (64) bytes from the
//! blob's first byte (zero padding before it, written by [`encode`], checked by [`decode`]): a
//! blob placed at a word-aligned address has word-aligned weights, which the Cortex-M4F kernels
//! load several words per instruction (`vldm`, `ldrd`), and one placed on a 64-byte boundary
//! (`AlignedBlob`, with `std`, on the host) has every weight array on a cache line, so no vector
//! load of the host kernels straddles two lines.
//!
//! Weight layouts are fixed by each layer's storage ([`Quantization::of_layer`]), chosen for
//! the inference kernels:
//! - f32: weights f32 LE in **blocks of [`F32_BLOCK`] outputs**, each block input-major
//!   ([`f32_weight_index`]: block `c` holds `w[i][8c..8c + 8]` for `i = 0, 1, ...`; the last
//!   `outputs % 8` outputs form a narrower block after them, so a layer narrower than 8 is plain
//!   input-major, the transpose of PyTorch's `[out][in]`). A layer is a sequence of axpy updates
//!   over the output vector, and a tile of 8 outputs reads its weights as one contiguous run
//!   (the Cortex-M4F loads 16 of them per `vldmia`); bias f32 LE.
//! - int8: weights i8 in **row pairs** ([`int8_weight_bytes`]): rows `2p` and `2p + 1` share
//!   `2 * inputs` bytes, input `i` at bytes `2i` (row `2p`'s weight plus 128, as u8) and
//!   `2i + 1` (row `2p + 1`'s, as i8); an odd last row follows as `inputs` i8. Each
//!   little-endian i16 of a pair is then `256 b + a + 128` (`a`, `b` the two rows' weights), so
//!   one 16 x 16 multiply-add serves both rows, and `b` is that i16 shifted right by 8: the
//!   Cortex-M4F kernel makes 4 multiply-adds of 3 instructions (`smlad`, `sxtb16`, `smlad`),
//!   and recovers row `2p` exactly from `256 S_b + S_a + 128 sum(x)`. One f32 scale per output
//!   channel (symmetric, zero point 0);
//!   bias i32 LE in units of `input_scale * weight_scale[j]`; the layer input is quantized
//!   symmetrically to 16 bits (`±ACTIVATION_LEVELS`) with `input_scale` (calibrated on the
//!   ground).
//!
//! Versions: 1 quantized int8 activations to ±127; 2 to 16 bits; 3 keeps the first and last
//! layers of an `Int8` network in f32 and aligns the weight arrays; 4 ends the payload with the
//! mission the network flies ([`BlobMission`]: its guidance cycle, canonical units and family);
//! 5 stores f32 weights in blocks of 8 outputs and int8 weights in row pairs. Only version 5 is
//! read: an older blob is refused with
//! [`BlobError::UnsupportedVersion`] and is re-exported from its actor (`ground model export`
//! gives the same network, bit for bit, in the new layout).

use serde::{Deserialize, Serialize};

pub use crate::scenario::ProblemKind;

/// First four bytes of every blob.
pub const MAGIC: [u8; 4] = *b"LTGB";
/// The format version this crate writes and reads.
pub const FORMAT_VERSION: u16 = 5;
/// The previous format version (f32 weights input-major, int8 output-major), which
/// [`upgrade`] converts.
#[cfg(feature = "std")]
pub const FORMAT_4: u16 = 4;
/// Format 4 without the mission at the end of the payload (read as [`BlobMission::THESIS`]),
/// which [`upgrade`] converts too.
#[cfg(feature = "std")]
pub const FORMAT_3: u16 = 3;
/// Outputs per block of an f32 layer's weights (see [`f32_weight_index`]).
pub const F32_BLOCK: usize = 8;
/// Each weight array starts at a multiple of this many bytes from the start of the blob: a
/// cache line, which covers the Cortex-M4F's word alignment too.
pub const WEIGHT_ALIGN: usize = 64;
/// The zero bytes [`encode`] pads with.
static PADDING: [u8; WEIGHT_ALIGN - 1] = [0; WEIGHT_ALIGN - 1];
/// Bytes before the payload: magic, version, payload length.
pub const HEADER_LEN: usize = 10;
/// Bytes after the payload: the CRC-32.
pub const TRAILER_LEN: usize = 4;
/// Most layers a network may have.
pub const MAX_LAYERS: usize = 4;
/// Largest layer width accepted (inputs or outputs).
pub const MAX_WIDTH: usize = 1024;
/// `Int8` activations are quantized to `-ACTIVATION_LEVELS..=ACTIVATION_LEVELS` (16-bit: the
/// inputs mix quantities of very different size, a time to go of ~10 next to radius gaps of
/// 0.01, which 127 levels cannot resolve; the i8 x i16 products still sum exactly in i32).
pub const ACTIVATION_LEVELS: i16 = 32_767;
/// Most inputs an `Int8` layer may have so its i32 accumulator cannot overflow:
/// `inputs * 32767 * 128 < 2^31`.
pub const MAX_INT8_INPUTS: usize = 512;

/// The network's input encoding (docs/spec.md sections 5 and 6).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum FeatureLayout {
    /// The 10 transfer features with the target-orbit proxy; 3 action outputs.
    TransferPolar10,
    /// The 22 rendezvous features; 3 action outputs.
    RendezvousPolar22,
    /// The 15 three-dimensional transfer features (docs/spec.md section 6.1); 4 action outputs
    /// (throttle and an RTN direction).
    TransferSpatial15,
    /// The 30 three-dimensional rendezvous features (docs/spec.md section 6.1); 4 action outputs.
    RendezvousSpatial30,
}

impl FeatureLayout {
    /// Number of network inputs.
    // Never zero, so an `is_empty` would only be noise.
    #[allow(clippy::len_without_is_empty)]
    pub fn len(self) -> usize {
        match self {
            Self::TransferPolar10 => 10,
            Self::RendezvousPolar22 => 22,
            Self::TransferSpatial15 => 15,
            Self::RendezvousSpatial30 => 30,
        }
    }

    /// The problem this layout encodes.
    pub fn problem(self) -> ProblemKind {
        match self {
            Self::TransferPolar10 | Self::TransferSpatial15 => ProblemKind::Transfer,
            Self::RendezvousPolar22 | Self::RendezvousSpatial30 => ProblemKind::Rendezvous,
        }
    }

    /// Whether the layout is three-dimensional.
    pub fn is_spatial(self) -> bool {
        matches!(self, Self::TransferSpatial15 | Self::RendezvousSpatial30)
    }

    /// Number of network outputs (action components): 3 in the plane, 4 in three dimensions.
    pub fn actions(self) -> usize {
        if self.is_spatial() {
            4
        } else {
            3
        }
    }

    /// The layout of `problem`'s features, planar or three-dimensional.
    pub fn of(problem: ProblemKind, spatial: bool) -> Self {
        match (problem, spatial) {
            (ProblemKind::Transfer, false) => Self::TransferPolar10,
            (ProblemKind::Rendezvous, false) => Self::RendezvousPolar22,
            (ProblemKind::Transfer, true) => Self::TransferSpatial15,
            (ProblemKind::Rendezvous, true) => Self::RendezvousSpatial30,
        }
    }
}

/// How the weights are stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Quantization {
    /// f32 weights and biases.
    F32,
    /// int8 per-output-channel symmetric weights, i32 bias, 16-bit activations, in the hidden
    /// layers between the first and the last, which stay f32 (see [`Quantization::of_layer`]).
    Int8,
}

impl Quantization {
    /// How layer `index` of a network of `layers` layers with this quantization is stored:
    /// every layer of an `F32` network; in an `Int8` network the hidden layers between the
    /// first and the last in int8, the first and the last in f32. The first layer's weights form
    /// small differences of large, nearly equal features (the target radius against the radius,
    /// with weights of ~46) that 8 bits cannot resolve; the last layer's outputs are the actions
    /// themselves, one scale per action over 256 weights. Together they hold under 5 % of the
    /// multiply-adds of the deployed networks.
    pub fn of_layer(self, index: usize, layers: usize) -> Quantization {
        match self {
            Self::F32 => Self::F32,
            Self::Int8 if index == 0 || index + 1 >= layers => Self::F32,
            Self::Int8 => Self::Int8,
        }
    }
}

/// A layer's output non-linearity.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Activation {
    /// Rectified linear unit, `max(x, 0)`: the hidden layers.
    Relu,
    /// Hyperbolic tangent: the output layer, so every action component lies in [-1, 1].
    Tanh,
}

/// One dense layer, borrowing its arrays from the blob bytes.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LayerBlob<'a> {
    /// Input width (1..=[`MAX_WIDTH`]).
    pub inputs: u16,
    /// Output width (1..=[`MAX_WIDTH`]).
    pub outputs: u16,
    /// The non-linearity applied to this layer's output.
    pub activation: Activation,
    /// `0..WEIGHT_ALIGN` zero bytes that put `weights` at a multiple of [`WEIGHT_ALIGN`] bytes
    /// from the start of the blob. [`encode`] writes them whatever the view holds.
    #[serde(borrow)]
    pub padding: &'a [u8],
    /// f32: `inputs * outputs * 4` bytes in blocks of 8 outputs ([`f32_weight_index`]); int8:
    /// `inputs * outputs` bytes in row pairs ([`int8_weight_bytes`]).
    #[serde(borrow)]
    pub weights: &'a [u8],
    /// f32: `outputs` f32 LE; int8: `outputs` i32 LE.
    #[serde(borrow)]
    pub bias: &'a [u8],
    /// int8 only: `outputs` f32 LE per-channel weight scales (empty for f32).
    #[serde(borrow)]
    pub weight_scales: &'a [u8],
    /// int8 only: the scale that quantizes this layer's input to `±ACTIVATION_LEVELS` (1.0 for f32).
    pub input_scale: f32,
}

/// What the flight code must know of the mission a network was trained for: the length of its
/// guidance cycle and the canonical units its features are in (docs/missions.md), and the
/// family's fingerprint, so that a blob is never flown for another family unnoticed.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BlobMission {
    /// The guidance cycle, t* (0 when the family cuts flights of different lengths into a
    /// count of cycles each: the length differs per flight and the flight software gives it).
    pub cycle: f64,
    /// The canonical length unit, m.
    pub length_unit_m: f64,
    /// The canonical time unit, s.
    pub time_unit_s: f64,
    /// The family's fingerprint (`shared::mission::MissionFamily::fingerprint`; 0: any family
    /// of the thesis's units and cycle).
    pub family: u32,
}

impl BlobMission {
    /// The thesis's: 14-day cycles, AU and the Sun's time unit, any family.
    pub const THESIS: Self = Self {
        cycle: crate::units::STEP,
        length_unit_m: crate::units::AU_M,
        time_unit_s: crate::units::TIME_UNIT_S,
        family: 0,
    };

    /// The cycle is finite and >= 0, the units finite and > 0.
    pub fn is_valid(&self) -> bool {
        let positive = |x: f64| x.is_finite() && x > 0.0;
        self.cycle.is_finite() && self.cycle >= 0.0 && positive(self.length_unit_m) && positive(self.time_unit_s)
    }
}

impl Default for BlobMission {
    fn default() -> Self {
        Self::THESIS
    }
}

/// The payload: a self-describing actor mean network.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NetworkBlob<'a> {
    /// The problem the network flies (transfer or rendezvous).
    pub kind: ProblemKind,
    /// The input encoding the network was trained on.
    pub features: FeatureLayout,
    /// How the weight arrays are stored (per layer: [`Quantization::of_layer`]).
    pub quantization: Quantization,
    /// Free text: config hash, training run, date. Never interpreted.
    #[serde(borrow)]
    pub provenance: &'a str,
    /// The dense layers, input to output (1..=[`MAX_LAYERS`]).
    #[serde(borrow)]
    pub layers: heapless::Vec<LayerBlob<'a>, MAX_LAYERS>,
    /// The mission the network flies.
    pub mission: BlobMission,
}

/// The CRC-32 of the trailer: the common zlib/PNG polynomial, so any tool can check a blob.
const CRC32: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// Which array of a layer an error is about.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ArrayKind {
    /// The weight matrix.
    Weights,
    /// The bias vector.
    Bias,
    /// The int8 per-output-channel weight scales.
    WeightScales,
}

impl core::fmt::Display for ArrayKind {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::Weights => "weights",
            Self::Bias => "bias",
            Self::WeightScales => "weight_scales",
        })
    }
}

/// Why postcard refused the payload (a `Copy` mirror of `postcard::Error`, which is not `Copy`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PayloadError {
    /// The payload ended inside a value.
    UnexpectedEnd,
    /// A variable-length integer is malformed or overflows.
    BadVarint,
    /// A bool byte is neither 0 nor 1.
    BadBool,
    /// A char is not a Unicode scalar value.
    BadChar,
    /// A string (the provenance) is not valid UTF-8.
    BadUtf8,
    /// An option tag is neither 0 nor 1.
    BadOption,
    /// An enum discriminant out of range.
    BadEnum,
    /// A value's encoding is invalid otherwise.
    BadEncoding,
    /// A serde-level refusal, e.g. an unknown enum variant or an over-long sequence.
    Invalid,
    /// Any other postcard error (also serialization failures when encoding).
    Other,
}

impl From<postcard::Error> for PayloadError {
    fn from(e: postcard::Error) -> Self {
        use postcard::Error as E;
        match e {
            E::DeserializeUnexpectedEnd => Self::UnexpectedEnd,
            E::DeserializeBadVarint => Self::BadVarint,
            E::DeserializeBadBool => Self::BadBool,
            E::DeserializeBadChar => Self::BadChar,
            E::DeserializeBadUtf8 => Self::BadUtf8,
            E::DeserializeBadOption => Self::BadOption,
            E::DeserializeBadEnum => Self::BadEnum,
            E::DeserializeBadEncoding => Self::BadEncoding,
            E::SerdeDeCustom => Self::Invalid,
            _ => Self::Other,
        }
    }
}

impl core::fmt::Display for PayloadError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::UnexpectedEnd => "payload ends inside a value",
            Self::BadVarint => "malformed varint",
            Self::BadBool => "bool not 0 or 1",
            Self::BadChar => "invalid char",
            Self::BadUtf8 => "provenance is not valid UTF-8",
            Self::BadOption => "option tag not 0 or 1",
            Self::BadEnum => "enum discriminant out of range",
            Self::BadEncoding => "bad encoding",
            Self::Invalid => "value refused (unknown enum variant or too long a sequence)",
            Self::Other => "postcard error",
        })
    }
}

/// Every way a blob can be refused. `Copy` and allocation-free so the flight code can keep and
/// report it; the fields say where and by how much, for the ground operator.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BlobError {
    /// Fewer bytes than the header and trailer, or than the declared payload length needs.
    Truncated {
        /// Bytes needed.
        needed: usize,
        /// Bytes given.
        found: usize,
    },
    /// Bytes after the declared end of the blob.
    TrailingBytes {
        /// Bytes the header declares (header + payload + trailer).
        expected: usize,
        /// Bytes given.
        found: usize,
    },
    /// The first four bytes are not [`MAGIC`].
    BadMagic {
        /// The first four bytes.
        found: [u8; 4],
    },
    /// The header's format version is not [`FORMAT_VERSION`].
    UnsupportedVersion {
        /// The version in the header.
        found: u16,
        /// The version this build reads.
        supported: u16,
    },
    /// The payload's CRC-32 differs from the trailer's: the bytes were altered.
    CrcMismatch {
        /// The CRC-32 in the trailer.
        stored: u32,
        /// The CRC-32 of the payload as received.
        computed: u32,
    },
    /// postcard could not decode (or encode) the payload.
    Payload(PayloadError),
    /// postcard decoded a `NetworkBlob` but left bytes of the payload unread.
    PayloadNotConsumed {
        /// Bytes left over.
        unused: usize,
    },
    /// The feature layout belongs to another problem than `kind`.
    KindMismatch {
        /// The declared problem kind.
        kind: ProblemKind,
        /// The declared feature layout.
        features: FeatureLayout,
    },
    /// The network has no layers.
    NoLayers,
    /// The network has more than [`MAX_LAYERS`] layers.
    TooManyLayers {
        /// Layers in the blob.
        found: usize,
        /// Most layers supported ([`MAX_LAYERS`]).
        max: usize,
    },
    /// The first layer's inputs differ from the feature count.
    InputMismatch {
        /// Features of the declared layout.
        expected: usize,
        /// Inputs of the first layer.
        found: u16,
    },
    /// The last layer's output width is not the feature layout's action count
    /// ([`FeatureLayout::actions`]).
    OutputMismatch {
        /// Outputs the layout flies.
        expected: usize,
        /// Outputs of the last layer.
        found: u16,
    },
    /// Layer `layer`'s inputs differ from the previous layer's outputs.
    ChainBreak {
        /// Index of the layer (from 0).
        layer: usize,
        /// Outputs of the previous layer.
        expected: u16,
        /// Inputs of this layer.
        found: u16,
    },
    /// A width is zero or above [`MAX_WIDTH`].
    BadWidth {
        /// Index of the layer (from 0).
        layer: usize,
        /// Declared input width.
        inputs: u16,
        /// Declared output width.
        outputs: u16,
    },
    /// An array's byte length does not match the layer shape and quantization.
    ArrayLength {
        /// Index of the layer (from 0).
        layer: usize,
        /// Which array.
        array: ArrayKind,
        /// Bytes the shape and quantization need.
        expected: usize,
        /// Bytes in the blob.
        found: usize,
    },
    /// Hidden layers must be ReLU, the output layer Tanh.
    BadActivation {
        /// Index of the layer (from 0).
        layer: usize,
        /// The activation the contract requires there.
        expected: Activation,
        /// The activation in the blob.
        found: Activation,
    },
    /// A scale is non-finite or not positive; `channel` is `None` for `input_scale`, `bits` the
    /// raw f32 (kept as bits so the error stays `Eq`).
    BadScale {
        /// Index of the layer (from 0).
        layer: usize,
        /// Output channel of a weight scale, or `None` for the input scale.
        channel: Option<usize>,
        /// The scale's f32 bits.
        bits: u32,
    },
    /// A non-finite f32 weight or bias, at element `index`.
    NonFiniteWeight {
        /// Index of the layer (from 0).
        layer: usize,
        /// Which array.
        array: ArrayKind,
        /// Element index in the array.
        index: usize,
    },
    /// A layer's padding is not the fewest zero bytes (`0..WEIGHT_ALIGN`) that put its weights
    /// at a multiple of [`WEIGHT_ALIGN`] from the start of the blob, as [`encode`] writes it.
    BadPadding {
        /// Index of the layer (from 0).
        layer: usize,
        /// Padding bytes in the blob.
        len: usize,
        /// Byte offset of the weights from the start of the blob.
        weights_offset: usize,
    },
    /// The output buffer given to [`encode`] is too small.
    BufferTooSmall {
        /// Bytes the blob needs.
        needed: usize,
        /// Bytes in the buffer.
        available: usize,
    },
    /// The payload does not fit the u32 length field.
    PayloadTooLarge {
        /// Payload bytes.
        len: usize,
    },
    /// The mission's cycle is negative or not finite, or a unit is not finite and positive.
    BadMission,
}

impl core::fmt::Display for BlobError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            Self::Truncated { needed, found } => {
                write!(f, "blob truncated: {found} bytes, needs {needed}")
            }
            Self::TrailingBytes { expected, found } => write!(
                f,
                "blob has {} trailing bytes: {found} bytes, header declares {expected}",
                found - expected.min(found)
            ),
            Self::BadMagic { found } => write!(f, "bad magic {found:02x?}, expected \"LTGB\""),
            Self::UnsupportedVersion { found, supported } => write!(
                f,
                "unsupported blob format version {found} (this build reads version {supported}; re-export an older blob from its actor)"
            ),
            Self::CrcMismatch { stored, computed } => write!(
                f,
                "payload CRC-32 mismatch: stored {stored:#010x}, computed {computed:#010x}"
            ),
            Self::Payload(e) => write!(f, "payload encoding: {e}"),
            Self::PayloadNotConsumed { unused } => {
                write!(f, "payload has {unused} bytes after the network description")
            }
            Self::KindMismatch { kind, features } => {
                write!(f, "problem kind {kind:?} does not match feature layout {features:?}")
            }
            Self::NoLayers => f.write_str("network has no layers"),
            Self::BadMission => {
                f.write_str("the mission's cycle must be finite and >= 0 t*, its length and time units finite and > 0")
            }
            Self::TooManyLayers { found, max } => {
                write!(f, "network has {found} layers, at most {max} supported")
            }
            Self::InputMismatch { expected, found } => {
                write!(f, "first layer takes {found} inputs, the feature layout has {expected}")
            }
            Self::OutputMismatch { expected, found } => {
                write!(
                    f,
                    "last layer gives {found} outputs, the feature layout flies {expected} action components"
                )
            }
            Self::ChainBreak { layer, expected, found } => {
                write!(f, "layer {layer} takes {found} inputs, previous layer gives {expected}")
            }
            Self::BadWidth { layer, inputs, outputs } => {
                write!(f, "layer {layer} is {inputs}x{outputs}: widths must be 1..={MAX_WIDTH}")
            }
            Self::ArrayLength {
                layer,
                array,
                expected,
                found,
            } => write!(
                f,
                "layer {layer} {array}: {found} bytes, shape and quantization need {expected}"
            ),
            Self::BadActivation { layer, expected, found } => {
                write!(f, "layer {layer} activation {found:?}, expected {expected:?}")
            }
            Self::BadScale {
                layer,
                channel: None,
                bits,
            } => write!(
                f,
                "layer {layer} input_scale {} is not finite and positive",
                crate::decimal::Decimal6(f64::from(f32::from_bits(bits)))
            ),
            Self::BadScale {
                layer,
                channel: Some(c),
                bits,
            } => write!(
                f,
                "layer {layer} weight scale {c} = {} is not finite and positive",
                crate::decimal::Decimal6(f64::from(f32::from_bits(bits)))
            ),
            Self::NonFiniteWeight { layer, array, index } => {
                write!(f, "layer {layer} {array}[{index}] is not finite")
            }
            Self::BadPadding {
                layer,
                len,
                weights_offset,
            } => write!(
                f,
                "layer {layer}: {len} padding bytes put the weights at byte {weights_offset}; \
                 the fewest zero bytes (at most {WEIGHT_ALIGN} - 1) that reach a multiple of \
                 {WEIGHT_ALIGN}, with every field before them in its shortest encoding"
            ),
            Self::BufferTooSmall { needed, available } => {
                write!(f, "output buffer of {available} bytes, blob needs {needed}")
            }
            Self::PayloadTooLarge { len } => {
                write!(f, "payload of {len} bytes does not fit the u32 length field")
            }
        }
    }
}

// `core::error::Error` is `std::error::Error`; implementing it in core serves both builds.
impl core::error::Error for BlobError {}
impl core::error::Error for PayloadError {}

/// Reads the `i`-th little-endian f32 of `bytes`; `None` past the end. Blob arrays are
/// unaligned byte slices, so they are read element by element, never cast.
pub fn f32_at(bytes: &[u8], i: usize) -> Option<f32> {
    le4(bytes, i).map(f32::from_le_bytes)
}

/// Reads the `i`-th little-endian i32 of `bytes`; `None` past the end.
pub fn i32_at(bytes: &[u8], i: usize) -> Option<i32> {
    le4(bytes, i).map(i32::from_le_bytes)
}

/// All complete little-endian f32 of `bytes`, in order.
pub fn f32s(bytes: &[u8]) -> impl Iterator<Item = f32> + '_ {
    // Fixed-size chunks, not indexed slices: no bounds check, so no panic path reaches a
    // flight image however the optimizer inlines the callers.
    bytes.as_chunks::<4>().0.iter().map(|c| f32::from_le_bytes(*c))
}

fn le4(bytes: &[u8], i: usize) -> Option<[u8; 4]> {
    let start = i.checked_mul(4)?;
    let b = bytes.get(start..start.checked_add(4)?)?;
    b.try_into().ok()
}

/// A copy of a blob's bytes placed on a 64-byte ([`WEIGHT_ALIGN`]) boundary, so that every
/// weight array is on a cache line (host inference runs about a fifth faster than with weights
/// straddling lines; docs/history/onboard.md). Flight code links its blob aligned instead.
#[cfg(feature = "std")]
#[derive(Debug, Clone)]
pub struct AlignedBlob {
    buf: std::vec::Vec<u8>,
    start: usize,
    len: usize,
}

#[cfg(feature = "std")]
impl AlignedBlob {
    /// Copies `bytes` to a 64-byte boundary.
    pub fn new(bytes: &[u8]) -> Self {
        let mut buf = std::vec![0u8; bytes.len() + WEIGHT_ALIGN];
        // The heap buffer does not move with the Vec, so the offset stays right.
        let start = (WEIGHT_ALIGN - buf.as_ptr() as usize % WEIGHT_ALIGN) % WEIGHT_ALIGN;
        buf[start..start + bytes.len()].copy_from_slice(bytes);
        Self {
            buf,
            start,
            len: bytes.len(),
        }
    }

    /// The blob's bytes, starting on a 64-byte boundary.
    pub fn bytes(&self) -> &[u8] {
        &self.buf[self.start..self.start + self.len]
    }
}

/// f32 values as the LE bytes a blob array holds (for the ground exporter).
#[cfg(feature = "std")]
pub fn f32_le_bytes(values: &[f32]) -> std::vec::Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

/// i32 values as the LE bytes a blob array holds (Int8 biases).
#[cfg(feature = "std")]
pub fn i32_le_bytes(values: &[i32]) -> std::vec::Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

/// Where weight `(j, i)` (output `j`, input `i`) of an f32 layer of `inputs` x `outputs` lies,
/// in f32 from the start of its weights: in block `j / 8` of [`F32_BLOCK`] outputs (`8 inputs`
/// f32 each, input-major within), or, for the last `outputs % 8` outputs, in the narrower block
/// after the whole ones. For `outputs < 8` this is the plain input-major `i * outputs + j`.
pub const fn f32_weight_index(inputs: usize, outputs: usize, j: usize, i: usize) -> usize {
    let whole = outputs - outputs % F32_BLOCK;
    if j < whole {
        inputs * (j - j % F32_BLOCK) + F32_BLOCK * i + j % F32_BLOCK
    } else {
        inputs * whole + (outputs - whole) * i + (j - whole)
    }
}

/// An f32 layer's weights, output-major (`weights[j * inputs + i]`, PyTorch's layout), as the
/// LE bytes a blob holds ([`f32_weight_index`]). `weights.len()` is `inputs * outputs`; a length
/// that is not (or `inputs == 0`) gives the bytes of the whole rows only, which the decoder
/// then refuses by length.
#[cfg(feature = "std")]
pub fn f32_weight_bytes(weights: &[f32], inputs: usize) -> std::vec::Vec<u8> {
    if inputs == 0 {
        return std::vec::Vec::new();
    }
    let outputs = weights.len() / inputs;
    let mut stored = std::vec![0.0f32; inputs * outputs];
    for (j, row) in weights.chunks_exact(inputs).enumerate() {
        for (i, &w) in row.iter().enumerate() {
            stored[f32_weight_index(inputs, outputs, j, i)] = w;
        }
    }
    f32_le_bytes(&stored)
}

/// A blob of an older format in the present one: the same network, bit for bit, with its
/// weights laid out anew (f32 in blocks, int8 in row pairs). Format 4 ([`FORMAT_4`]) has the
/// present payload's structure, only the weights' order differs; format 3 ([`FORMAT_3`]) lacks
/// the mission, which becomes the thesis's ([`BlobMission::THESIS`]). A present-format blob comes
/// back unchanged; anything else is refused as [`decode`] refuses it (a format-3 or 4 blob whose
/// CRC or length does not match, as a present one would be).
#[cfg(feature = "std")]
pub fn upgrade(bytes: &[u8]) -> Result<std::vec::Vec<u8>, BlobError> {
    let version = bytes.get(4..6).map(|v| u16::from_le_bytes([v[0], v[1]]));
    if version == Some(FORMAT_3) {
        // Checked as the present format (framing, CRC) with the version patched, the mission
        // appended to the payload, then framed again as format 4.
        let mut checked = bytes.to_vec();
        checked[4..6].copy_from_slice(&FORMAT_VERSION.to_le_bytes());
        if let Err(
            e @ (BlobError::Truncated { .. } | BlobError::TrailingBytes { .. } | BlobError::CrcMismatch { .. }),
        ) = decode(&checked)
        {
            return Err(e);
        }
        let mut payload = bytes[HEADER_LEN..bytes.len() - TRAILER_LEN].to_vec();
        let mission = postcard::to_allocvec(&BlobMission::THESIS).map_err(|e| BlobError::Payload(e.into()))?;
        payload.extend(mission);
        let len = u32::try_from(payload.len()).map_err(|_| BlobError::Payload(PayloadError::Other))?;
        let mut framed = std::vec::Vec::with_capacity(payload.len() + HEADER_LEN + TRAILER_LEN);
        framed.extend(MAGIC);
        framed.extend(FORMAT_4.to_le_bytes());
        framed.extend(len.to_le_bytes());
        framed.extend(&payload);
        framed.extend(CRC32.checksum(&payload).to_le_bytes());
        return upgrade(&framed);
    }
    if version != Some(FORMAT_4) {
        decode(bytes)?;
        return Ok(bytes.to_vec());
    }
    let mut current = bytes.to_vec();
    current[4..6].copy_from_slice(&FORMAT_VERSION.to_le_bytes());
    let old = decode(&current)?;
    let mut arrays: std::vec::Vec<std::vec::Vec<u8>> = std::vec::Vec::new();
    for l in &old.layers {
        let (inputs, outputs) = (usize::from(l.inputs), usize::from(l.outputs));
        let stored = match old.quantization.of_layer(arrays.len(), old.layers.len()) {
            Quantization::F32 => {
                let input_major: std::vec::Vec<f32> = f32s(l.weights).collect();
                let rows: std::vec::Vec<f32> = (0..inputs * outputs)
                    .map(|k| input_major[(k % inputs) * outputs + k / inputs])
                    .collect();
                f32_weight_bytes(&rows, inputs)
            }
            Quantization::Int8 => {
                let rows: std::vec::Vec<i8> = l.weights.iter().map(|&b| b as i8).collect();
                int8_weight_bytes(&rows, inputs)
            }
        };
        arrays.push(stored);
    }
    let mut new = old.clone();
    for (layer, weights) in new.layers.iter_mut().zip(&arrays) {
        layer.weights = weights;
    }
    encode_to_vec(&new)
}

/// An int8 layer's weights, output-major (`weights[j * inputs + i]`, PyTorch's layout), as the
/// bytes a blob holds: in row pairs (see the module doc). `weights.len()` is `inputs * outputs`;
/// a length that is not a multiple of `inputs` (or `inputs == 0`) gives the bytes of the whole
/// rows only, which the decoder then refuses by length.
#[cfg(feature = "std")]
pub fn int8_weight_bytes(weights: &[i8], inputs: usize) -> std::vec::Vec<u8> {
    let mut out = std::vec::Vec::with_capacity(weights.len());
    if inputs == 0 {
        return out;
    }
    let mut pairs = weights.chunks_exact(2 * inputs);
    for pair in pairs.by_ref() {
        let (a, b) = pair.split_at(inputs);
        for (&wa, &wb) in a.iter().zip(b) {
            out.push((wa as u8) ^ 0x80);
            out.push(wb as u8);
        }
    }
    if let Some(last) = pairs.remainder().chunks_exact(inputs).next() {
        out.extend(last.iter().map(|&w| w as u8));
    }
    out
}

/// Weight `(j, i)` (output `j`, input `i`) of an int8 layer of `inputs` x `outputs` stored by
/// [`int8_weight_bytes`]; `None` outside the layer or the bytes.
pub fn int8_weight_at(bytes: &[u8], inputs: usize, outputs: usize, j: usize, i: usize) -> Option<i8> {
    if i >= inputs || j >= outputs {
        return None;
    }
    let pair_start = (j / 2).checked_mul(2 * inputs)?;
    let at = if j / 2 < outputs / 2 {
        pair_start + 2 * i + j % 2
    } else {
        pair_start + i
    };
    let byte = *bytes.get(at)?;
    Some(if j / 2 < outputs / 2 && j.is_multiple_of(2) {
        (byte ^ 0x80) as i8
    } else {
        byte as i8
    })
}

impl LayerBlob<'_> {
    /// Byte lengths `[weights, bias, weight_scales]` this layer's shape needs when stored as `q`
    /// (the layer's own storage, [`Quantization::of_layer`]).
    pub fn expected_lens(&self, q: Quantization) -> [usize; 3] {
        let (i, o) = (usize::from(self.inputs), usize::from(self.outputs));
        // u16 * u16 * 4 < 2^34: saturate rather than overflow on 32-bit targets.
        let n = i.saturating_mul(o);
        match q {
            Quantization::F32 => [n.saturating_mul(4), o * 4, 0],
            Quantization::Int8 => [n, o * 4, o * 4],
        }
    }
}

fn finite_positive(x: f32) -> bool {
    x.is_finite() && x > 0.0
}

impl NetworkBlob<'_> {
    /// Every semantic check, so a blob that passes can be run by the inference kernels without
    /// further bounds or shape checks (except the action size, which the onboard loader owns).
    pub fn validate(&self) -> Result<(), BlobError> {
        if !self.mission.is_valid() {
            return Err(BlobError::BadMission);
        }
        if self.features.problem() != self.kind {
            return Err(BlobError::KindMismatch {
                kind: self.kind,
                features: self.features,
            });
        }
        let n = self.layers.len();
        if n == 0 {
            return Err(BlobError::NoLayers);
        }
        if n > MAX_LAYERS {
            return Err(BlobError::TooManyLayers {
                found: n,
                max: MAX_LAYERS,
            });
        }
        // The previous layer's outputs, carried along rather than indexed: no bounds check, so
        // no panic path reaches flight images (the C interface's check looks for one).
        let mut previous_outputs: Option<u16> = None;
        for (l, layer) in self.layers.iter().enumerate() {
            let ok = |w: u16| w != 0 && usize::from(w) <= MAX_WIDTH;
            if !ok(layer.inputs) || !ok(layer.outputs) {
                return Err(BlobError::BadWidth {
                    layer: l,
                    inputs: layer.inputs,
                    outputs: layer.outputs,
                });
            }
            match previous_outputs {
                None => {
                    if usize::from(layer.inputs) != self.features.len() {
                        return Err(BlobError::InputMismatch {
                            expected: self.features.len(),
                            found: layer.inputs,
                        });
                    }
                }
                Some(prev) => {
                    if layer.inputs != prev {
                        return Err(BlobError::ChainBreak {
                            layer: l,
                            expected: prev,
                            found: layer.inputs,
                        });
                    }
                }
            }
            previous_outputs = Some(layer.outputs);
            if l + 1 == n && usize::from(layer.outputs) != self.features.actions() {
                return Err(BlobError::OutputMismatch {
                    expected: self.features.actions(),
                    found: layer.outputs,
                });
            }
            let want = if l + 1 == n { Activation::Tanh } else { Activation::Relu };
            if layer.activation != want {
                return Err(BlobError::BadActivation {
                    layer: l,
                    expected: want,
                    found: layer.activation,
                });
            }
            let arrays = [
                (ArrayKind::Weights, layer.weights),
                (ArrayKind::Bias, layer.bias),
                (ArrayKind::WeightScales, layer.weight_scales),
            ];
            let q = self.quantization.of_layer(l, n);
            for ((array, bytes), expected) in arrays.into_iter().zip(layer.expected_lens(q)) {
                if bytes.len() != expected {
                    return Err(BlobError::ArrayLength {
                        layer: l,
                        array,
                        expected,
                        found: bytes.len(),
                    });
                }
            }
            if !finite_positive(layer.input_scale) {
                return Err(BlobError::BadScale {
                    layer: l,
                    channel: None,
                    bits: layer.input_scale.to_bits(),
                });
            }
            match q {
                Quantization::F32 => {
                    for (array, bytes) in [(ArrayKind::Weights, layer.weights), (ArrayKind::Bias, layer.bias)] {
                        if let Some(index) = f32s(bytes).position(|v| !v.is_finite()) {
                            return Err(BlobError::NonFiniteWeight { layer: l, array, index });
                        }
                    }
                }
                Quantization::Int8 => {
                    if let Some((c, s)) = f32s(layer.weight_scales)
                        .enumerate()
                        .find(|&(_, s)| !finite_positive(s))
                    {
                        return Err(BlobError::BadScale {
                            layer: l,
                            channel: Some(c),
                            bits: s.to_bits(),
                        });
                    }
                }
            }
        }
        Ok(())
    }
}

/// Reads a LEB128 varint as postcard writes it (at most 10 bytes), advancing `pos`.
fn peek_varint(bytes: &[u8], pos: &mut usize) -> Option<u64> {
    let mut v = 0u64;
    for shift in (0..70).step_by(7) {
        let b = *bytes.get(*pos)?;
        *pos += 1;
        v |= u64::from(b & 0x7f).checked_shl(shift)?;
        if b & 0x80 == 0 {
            return Some(v);
        }
    }
    None
}

/// The layer count a payload declares, if its prefix (three enum tags, provenance) is well
/// formed. Only used to explain a postcard failure: heapless refuses an over-long layer list
/// with an anonymous serde error.
fn declared_layer_count(payload: &[u8]) -> Option<u64> {
    let mut pos = 0;
    for _ in 0..3 {
        if peek_varint(payload, &mut pos)? > 1 {
            return None;
        }
    }
    let str_len = usize::try_from(peek_varint(payload, &mut pos)?).ok()?;
    let end = pos.checked_add(str_len)?;
    core::str::from_utf8(payload.get(pos..end)?).ok()?;
    pos = end;
    peek_varint(payload, &mut pos)
}

/// Checks and decodes a blob in place, borrowing every array from `bytes`. Never panics,
/// never allocates, reads nothing outside `bytes`. The checks run cheapest and most
/// telling first: framing, magic, version, length, CRC, then the payload and its semantics.
pub fn decode(bytes: &[u8]) -> Result<NetworkBlob<'_>, BlobError> {
    let min = HEADER_LEN + TRAILER_LEN;
    if bytes.len() < min {
        return Err(BlobError::Truncated {
            needed: min,
            found: bytes.len(),
        });
    }
    let magic = [bytes[0], bytes[1], bytes[2], bytes[3]];
    if magic != MAGIC {
        return Err(BlobError::BadMagic { found: magic });
    }
    let version = u16::from_le_bytes([bytes[4], bytes[5]]);
    if version != FORMAT_VERSION {
        return Err(BlobError::UnsupportedVersion {
            found: version,
            supported: FORMAT_VERSION,
        });
    }
    let declared = u32::from_le_bytes([bytes[6], bytes[7], bytes[8], bytes[9]]);
    // On a 16-bit usize an unrepresentable length cannot fit in memory anyway.
    let total = usize::try_from(declared)
        .ok()
        .and_then(|l| l.checked_add(min))
        .unwrap_or(usize::MAX);
    if bytes.len() < total {
        return Err(BlobError::Truncated {
            needed: total,
            found: bytes.len(),
        });
    }
    if bytes.len() > total {
        return Err(BlobError::TrailingBytes {
            expected: total,
            found: bytes.len(),
        });
    }
    let payload = &bytes[HEADER_LEN..total - TRAILER_LEN];
    let t = &bytes[total - TRAILER_LEN..];
    let stored = u32::from_le_bytes([t[0], t[1], t[2], t[3]]);
    let computed = CRC32.checksum(payload);
    if stored != computed {
        return Err(BlobError::CrcMismatch { stored, computed });
    }
    let (blob, rest): (NetworkBlob<'_>, _) = match postcard::take_from_bytes::<NetworkBlob<'_>>(payload) {
        Ok(v) => v,
        Err(e) => {
            return Err(match declared_layer_count(payload) {
                Some(n) if n > MAX_LAYERS as u64 => BlobError::TooManyLayers {
                    found: usize::try_from(n).unwrap_or(usize::MAX),
                    max: MAX_LAYERS,
                },
                _ => BlobError::Payload(e.into()),
            })
        }
    };
    if !rest.is_empty() {
        return Err(BlobError::PayloadNotConsumed { unused: rest.len() });
    }
    // postcard also reads a varint written in more bytes than it needs; with the padding one
    // byte shorter the weights stay aligned, so only the padding [`encode`] writes is accepted:
    // whatever decodes re-encodes to the same network.
    let canonical = blob.aligned()?;
    for (layer, (l, c)) in blob.layers.iter().zip(&canonical.layers).enumerate() {
        // Both slices borrow from `bytes`, so the difference is the offset in the blob.
        let weights_offset = (l.weights.as_ptr() as usize).wrapping_sub(bytes.as_ptr() as usize);
        if l.padding.len() != c.padding.len()
            || l.padding.iter().any(|&b| b != 0)
            || !weights_offset.is_multiple_of(WEIGHT_ALIGN)
        {
            return Err(BlobError::BadPadding {
                layer,
                len: l.padding.len(),
                weights_offset,
            });
        }
    }
    blob.validate()?;
    Ok(blob)
}

/// The fields of a layer before its weights' length prefix, for [`NetworkBlob::aligned`].
#[derive(Serialize)]
struct LayerHead<'a> {
    inputs: u16,
    outputs: u16,
    activation: Activation,
    padding: &'a [u8],
}

fn serialized_len<T: Serialize + ?Sized>(value: &T) -> Result<usize, BlobError> {
    postcard::experimental::serialized_size(value).map_err(|e| BlobError::Payload(e.into()))
}

impl<'a> NetworkBlob<'a> {
    /// The same network with each layer's padding set so that its weights start at a multiple
    /// of [`WEIGHT_ALIGN`] bytes from the start of the encoded blob (what [`encode`] writes).
    pub fn aligned(&self) -> Result<NetworkBlob<'a>, BlobError> {
        let mut out = self.clone();
        out.layers.clear();
        // The payload before the layers (the mission comes after them); the layer count's varint
        // is one byte for any count up to MAX_LAYERS, so the empty list stands for the whole one.
        let mut at = HEADER_LEN + serialized_len(&out)? - serialized_len(&out.mission)?;
        for layer in &self.layers {
            let mut layer = *layer;
            let head = LayerHead {
                inputs: layer.inputs,
                outputs: layer.outputs,
                activation: layer.activation,
                padding: &[],
            };
            let unpadded = at + serialized_len(&head)? + serialized_len(&layer.weights.len())?;
            let pad = (WEIGHT_ALIGN - unpadded % WEIGHT_ALIGN) % WEIGHT_ALIGN;
            layer.padding = PADDING.get(..pad).unwrap_or(&[]);
            at += serialized_len(&layer)?;
            out.layers.push(layer).map_err(|_| BlobError::TooManyLayers {
                found: self.layers.len(),
                max: MAX_LAYERS,
            })?;
        }
        Ok(out)
    }
}

fn payload_len(blob: &NetworkBlob<'_>) -> Result<usize, BlobError> {
    postcard::experimental::serialized_size(blob).map_err(|e| BlobError::Payload(e.into()))
}

fn framed_len(payload: usize) -> Result<usize, BlobError> {
    if u32::try_from(payload).is_err() {
        return Err(BlobError::PayloadTooLarge { len: payload });
    }
    payload
        .checked_add(HEADER_LEN + TRAILER_LEN)
        .ok_or(BlobError::PayloadTooLarge { len: payload })
}

/// Total bytes [`encode`] will write for `blob` (validating it first).
pub fn encoded_len(blob: &NetworkBlob<'_>) -> Result<usize, BlobError> {
    blob.validate()?;
    framed_len(payload_len(&blob.aligned()?)?)
}

/// Validates `blob` and writes the framed blob, its weights aligned
/// ([`NetworkBlob::aligned`]; the view's own padding is ignored), to the start of `out`;
/// returns the bytes written. No heap, so the flight side could re-emit a blob too.
pub fn encode(blob: &NetworkBlob<'_>, out: &mut [u8]) -> Result<usize, BlobError> {
    blob.validate()?;
    encode_unchecked(&blob.aligned()?, out)
}

/// [`encode`] without [`NetworkBlob::validate`] and with the view's padding as it is: only for tests that need a correctly framed
/// blob with a semantic defect, to prove the decoder's own checks fire.
#[doc(hidden)]
pub fn encode_unchecked(blob: &NetworkBlob<'_>, out: &mut [u8]) -> Result<usize, BlobError> {
    let len = payload_len(blob)?;
    let total = framed_len(len)?;
    if out.len() < total {
        return Err(BlobError::BufferTooSmall {
            needed: total,
            available: out.len(),
        });
    }
    let (header, rest) = out.split_at_mut(HEADER_LEN);
    let (payload, rest) = rest.split_at_mut(len);
    let written = postcard::to_slice(blob, payload)
        .map_err(|e| BlobError::Payload(e.into()))?
        .len();
    if written != len {
        return Err(BlobError::Payload(PayloadError::Other));
    }
    header[..4].copy_from_slice(&MAGIC);
    header[4..6].copy_from_slice(&FORMAT_VERSION.to_le_bytes());
    // framed_len checked that len fits in u32.
    header[6..10].copy_from_slice(&(len as u32).to_le_bytes());
    rest[..TRAILER_LEN].copy_from_slice(&CRC32.checksum(payload).to_le_bytes());
    Ok(total)
}

/// [`encode`] into a new exactly sized vector (the ground exporter's entry point).
#[cfg(feature = "std")]
pub fn encode_to_vec(blob: &NetworkBlob<'_>) -> Result<std::vec::Vec<u8>, BlobError> {
    let mut out = std::vec![0u8; encoded_len(blob)?];
    let n = encode_unchecked(&blob.aligned()?, &mut out)?;
    debug_assert_eq!(n, out.len());
    Ok(out)
}
