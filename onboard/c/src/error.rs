//! The return codes of the C interface: 0 for success, one distinct negative code per refusal.
//!
//! Every variant of `BlobError`, `PolicyError` and `GuidanceError` has its own code, so
//! flight software can report exactly why a blob or a cycle was refused (telemetry, event
//! messages) without the Rust error values crossing the boundary. The matches below have no
//! wildcard arm: a new error variant in the onboard crates does not compile until it has a code.
//! Codes are grouped by tens: -1..-9 the call itself, -10..-29 the blob's bytes, -30..-39 the
//! network against the compiled controller, -40..-49 the guidance step.

use core::ffi::CStr;

use onboard::dynamics::StateError;
use onboard::features::FeatureError;
use onboard::guidance::GuidanceError;
use onboard::policy::PolicyError;
use shared::blob::BlobError;

pub use lt_status::*;

/// What a call of the C interface returned: `LT_OK`, or why it refused.
#[repr(i32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum lt_status {
    /// Success.
    LT_OK = 0,
    /// A required pointer argument is null.
    LT_ERR_NULL_POINTER = -1,
    /// The policy storage is not aligned to `lt_policy`'s alignment (8 bytes).
    LT_ERR_MISALIGNED_POLICY = -2,
    /// The blob length cannot describe memory: it exceeds `PTRDIFF_MAX` or wraps the address space.
    LT_ERR_BLOB_LENGTH = -3,
    /// The policy was never loaded, or its last load was refused: the caller commands thrust off.
    LT_ERR_NOT_LOADED = -4,
    /// A transfer step on a rendezvous policy, or a rendezvous step on a transfer policy.
    LT_ERR_WRONG_POLICY_KIND = -5,
    /// Fewer bytes than the header and trailer, or than the declared payload length needs.
    LT_ERR_BLOB_TRUNCATED = -10,
    /// Bytes after the end the header declares.
    LT_ERR_BLOB_TRAILING_BYTES = -11,
    /// The first four bytes are not `LTGB`.
    LT_ERR_BLOB_BAD_MAGIC = -12,
    /// The header's format version is not the one this library reads (see `lt_version`).
    LT_ERR_BLOB_UNSUPPORTED_VERSION = -13,
    /// The payload's CRC-32 differs from the trailer's: the bytes were altered.
    LT_ERR_BLOB_CRC_MISMATCH = -14,
    /// The payload passed the CRC but is not a valid network description.
    LT_ERR_BLOB_PAYLOAD = -15,
    /// The payload has bytes after the network description.
    LT_ERR_BLOB_PAYLOAD_NOT_CONSUMED = -16,
    /// The blob's problem kind and feature layout disagree.
    LT_ERR_BLOB_KIND_MISMATCH = -17,
    /// The network has no layers.
    LT_ERR_BLOB_NO_LAYERS = -18,
    /// The network has more layers than the format allows.
    LT_ERR_BLOB_TOO_MANY_LAYERS = -19,
    /// The first layer's inputs differ from the feature count.
    LT_ERR_BLOB_INPUT_MISMATCH = -20,
    /// A layer's inputs differ from the previous layer's outputs.
    LT_ERR_BLOB_CHAIN_BREAK = -21,
    /// A layer width is zero or above the format's maximum.
    LT_ERR_BLOB_BAD_WIDTH = -22,
    /// An array's byte length does not match its layer's shape and quantization.
    LT_ERR_BLOB_ARRAY_LENGTH = -23,
    /// Hidden layers must be ReLU and the output layer tanh.
    LT_ERR_BLOB_BAD_ACTIVATION = -24,
    /// A scale is not finite and positive.
    LT_ERR_BLOB_BAD_SCALE = -25,
    /// An f32 weight or bias is not finite.
    LT_ERR_BLOB_NON_FINITE_WEIGHT = -26,
    /// Encoding only (never returned by a load): the output buffer is too small.
    LT_ERR_BLOB_BUFFER_TOO_SMALL = -27,
    /// Encoding only (never returned by a load): the payload does not fit the length field.
    LT_ERR_BLOB_PAYLOAD_TOO_LARGE = -28,
    /// A layer's padding is not the zero bytes that put its weights at a multiple of 64 bytes
    /// from the start of the blob.
    LT_ERR_BLOB_BAD_PADDING = -29,
    /// The blob is for the other problem (a rendezvous blob loaded as transfer, or the reverse).
    LT_ERR_WRONG_PROBLEM = -30,
    /// The blob's feature layout is not the compiled network's input.
    LT_ERR_WRONG_FEATURES = -31,
    /// The network does not have the compiled three layers.
    LT_ERR_WRONG_LAYER_COUNT = -32,
    /// A layer's shape differs from the compiled network's (10 or 22 inputs, 256, 256, 3).
    LT_ERR_WRONG_SHAPE = -33,
    /// A layer's array has the wrong length for the compiled shape.
    LT_ERR_WRONG_ARRAY_LENGTH = -34,
    /// A layer's activation is not the contract's (ReLU, ReLU, tanh).
    LT_ERR_WRONG_ACTIVATION = -35,
    /// An int8 layer's input or weight scale is unusable.
    LT_ERR_INT8_BAD_SCALE = -36,
    /// An int8 layer has more inputs than its i32 accumulator sums exactly.
    LT_ERR_INT8_TOO_WIDE = -37,
    /// The blob's mission is unusable: its cycle negative or not finite, or a unit not finite
    /// and positive.
    LT_ERR_BLOB_BAD_MISSION = -38,
    /// The network's last layer does not give the feature layout's action count (3 planar, 4
    /// three-dimensional).
    LT_ERR_BLOB_OUTPUT_MISMATCH = -39,
    /// Guidance input refused: a navigation state component is NaN or infinite.
    LT_ERR_INPUT_NON_FINITE_STATE = -40,
    /// Guidance input refused: the spacecraft is at r = 0.
    LT_ERR_INPUT_ZERO_RADIUS = -41,
    /// Guidance input refused: the mass is zero or negative.
    LT_ERR_INPUT_NON_POSITIVE_MASS = -42,
    /// Guidance input refused: the target orbit is not closed and finite, or the body state is not
    /// finite with r > 0.
    LT_ERR_INPUT_TARGET = -43,
    /// Guidance input refused: the time to go is negative or not finite.
    LT_ERR_INPUT_TIME_TO_GO = -44,
    /// The network's action is not finite (an input far outside the trained range, or corrupt
    /// weights that passed the checks).
    LT_ERR_NON_FINITE_ACTION = -45,
    /// Lookahead refused: the spacecraft's thrust or exhaust speed is not finite and positive, or
    /// the settings are unusable (goals and floor must be finite and > 0, the fuel weight finite
    /// and >= 0, the thrust margin in [0, 1)).
    LT_ERR_INPUT_LOOKAHEAD = -46,
    /// Terminal targeting refused: the spacecraft's thrust or exhaust speed is not finite and
    /// positive, or the settings are unusable (cycles 1 to 8, iterations 1 to 64, goals finite
    /// and > 0).
    LT_ERR_INPUT_TERMINAL = -47,
    /// Guidance input refused: the velocity lies along the radius, so the spacecraft has no orbit
    /// plane (three-dimensional features are relative to it).
    LT_ERR_INPUT_NO_ORBIT_PLANE = -48,
}

/// Every code with its name, as `lt_error_name` returns it.
const ERROR_NAMES: [(lt_status, &CStr); 45] = [
    (LT_OK, c"ok"),
    (LT_ERR_NULL_POINTER, c"null_pointer"),
    (LT_ERR_MISALIGNED_POLICY, c"misaligned_policy"),
    (LT_ERR_BLOB_LENGTH, c"blob_length"),
    (LT_ERR_NOT_LOADED, c"not_loaded"),
    (LT_ERR_WRONG_POLICY_KIND, c"wrong_policy_kind"),
    (LT_ERR_BLOB_TRUNCATED, c"blob_truncated"),
    (LT_ERR_BLOB_TRAILING_BYTES, c"blob_trailing_bytes"),
    (LT_ERR_BLOB_BAD_MAGIC, c"blob_bad_magic"),
    (LT_ERR_BLOB_UNSUPPORTED_VERSION, c"blob_unsupported_version"),
    (LT_ERR_BLOB_CRC_MISMATCH, c"blob_crc_mismatch"),
    (LT_ERR_BLOB_PAYLOAD, c"blob_payload"),
    (LT_ERR_BLOB_PAYLOAD_NOT_CONSUMED, c"blob_payload_not_consumed"),
    (LT_ERR_BLOB_KIND_MISMATCH, c"blob_kind_mismatch"),
    (LT_ERR_BLOB_NO_LAYERS, c"blob_no_layers"),
    (LT_ERR_BLOB_TOO_MANY_LAYERS, c"blob_too_many_layers"),
    (LT_ERR_BLOB_INPUT_MISMATCH, c"blob_input_mismatch"),
    (LT_ERR_BLOB_CHAIN_BREAK, c"blob_chain_break"),
    (LT_ERR_BLOB_BAD_WIDTH, c"blob_bad_width"),
    (LT_ERR_BLOB_ARRAY_LENGTH, c"blob_array_length"),
    (LT_ERR_BLOB_BAD_ACTIVATION, c"blob_bad_activation"),
    (LT_ERR_BLOB_BAD_SCALE, c"blob_bad_scale"),
    (LT_ERR_BLOB_NON_FINITE_WEIGHT, c"blob_non_finite_weight"),
    (LT_ERR_BLOB_BUFFER_TOO_SMALL, c"blob_buffer_too_small"),
    (LT_ERR_BLOB_PAYLOAD_TOO_LARGE, c"blob_payload_too_large"),
    (LT_ERR_BLOB_BAD_PADDING, c"blob_bad_padding"),
    (LT_ERR_WRONG_PROBLEM, c"wrong_problem"),
    (LT_ERR_WRONG_FEATURES, c"wrong_features"),
    (LT_ERR_WRONG_LAYER_COUNT, c"wrong_layer_count"),
    (LT_ERR_WRONG_SHAPE, c"wrong_shape"),
    (LT_ERR_WRONG_ARRAY_LENGTH, c"wrong_array_length"),
    (LT_ERR_WRONG_ACTIVATION, c"wrong_activation"),
    (LT_ERR_INT8_BAD_SCALE, c"int8_bad_scale"),
    (LT_ERR_INT8_TOO_WIDE, c"int8_too_wide"),
    (LT_ERR_BLOB_BAD_MISSION, c"blob_bad_mission"),
    (LT_ERR_BLOB_OUTPUT_MISMATCH, c"blob_output_mismatch"),
    (LT_ERR_INPUT_NON_FINITE_STATE, c"input_non_finite_state"),
    (LT_ERR_INPUT_ZERO_RADIUS, c"input_zero_radius"),
    (LT_ERR_INPUT_NON_POSITIVE_MASS, c"input_non_positive_mass"),
    (LT_ERR_INPUT_TARGET, c"input_target"),
    (LT_ERR_INPUT_TIME_TO_GO, c"input_time_to_go"),
    (LT_ERR_NON_FINITE_ACTION, c"non_finite_action"),
    (LT_ERR_INPUT_LOOKAHEAD, c"input_lookahead"),
    (LT_ERR_INPUT_TERMINAL, c"input_terminal"),
    (LT_ERR_INPUT_NO_ORBIT_PLANE, c"input_no_orbit_plane"),
];

/// What `error_name` says for a value that is not a code.
pub const UNKNOWN_CODE_NAME: &CStr = c"unknown";

/// Every code the library returns, `LT_OK` first.
pub fn all_codes() -> impl Iterator<Item = lt_status> {
    ERROR_NAMES.iter().map(|&(code, _)| code)
}

/// The name of `code` (`UNKNOWN_CODE_NAME` for a value that is not a code).
pub fn error_name(code: i32) -> &'static CStr {
    ERROR_NAMES
        .iter()
        .find(|&&(c, _)| c as i32 == code)
        .map_or(UNKNOWN_CODE_NAME, |&(_, name)| name)
}

/// The code of a blob refusal.
pub fn blob_error_code(error: &BlobError) -> lt_status {
    match error {
        BlobError::Truncated { .. } => LT_ERR_BLOB_TRUNCATED,
        BlobError::TrailingBytes { .. } => LT_ERR_BLOB_TRAILING_BYTES,
        BlobError::BadMagic { .. } => LT_ERR_BLOB_BAD_MAGIC,
        BlobError::UnsupportedVersion { .. } => LT_ERR_BLOB_UNSUPPORTED_VERSION,
        BlobError::CrcMismatch { .. } => LT_ERR_BLOB_CRC_MISMATCH,
        BlobError::Payload(_) => LT_ERR_BLOB_PAYLOAD,
        BlobError::PayloadNotConsumed { .. } => LT_ERR_BLOB_PAYLOAD_NOT_CONSUMED,
        BlobError::KindMismatch { .. } => LT_ERR_BLOB_KIND_MISMATCH,
        BlobError::NoLayers => LT_ERR_BLOB_NO_LAYERS,
        BlobError::TooManyLayers { .. } => LT_ERR_BLOB_TOO_MANY_LAYERS,
        BlobError::InputMismatch { .. } => LT_ERR_BLOB_INPUT_MISMATCH,
        BlobError::OutputMismatch { .. } => LT_ERR_BLOB_OUTPUT_MISMATCH,
        BlobError::ChainBreak { .. } => LT_ERR_BLOB_CHAIN_BREAK,
        BlobError::BadWidth { .. } => LT_ERR_BLOB_BAD_WIDTH,
        BlobError::ArrayLength { .. } => LT_ERR_BLOB_ARRAY_LENGTH,
        BlobError::BadActivation { .. } => LT_ERR_BLOB_BAD_ACTIVATION,
        BlobError::BadScale { .. } => LT_ERR_BLOB_BAD_SCALE,
        BlobError::NonFiniteWeight { .. } => LT_ERR_BLOB_NON_FINITE_WEIGHT,
        BlobError::BufferTooSmall { .. } => LT_ERR_BLOB_BUFFER_TOO_SMALL,
        BlobError::PayloadTooLarge { .. } => LT_ERR_BLOB_PAYLOAD_TOO_LARGE,
        BlobError::BadPadding { .. } => LT_ERR_BLOB_BAD_PADDING,
        BlobError::BadMission => LT_ERR_BLOB_BAD_MISSION,
    }
}

/// The code of a refused load.
pub fn policy_error_code(error: &PolicyError) -> lt_status {
    match error {
        PolicyError::Blob(e) => blob_error_code(e),
        PolicyError::WrongKind { .. } => LT_ERR_WRONG_PROBLEM,
        PolicyError::WrongFeatures { .. } => LT_ERR_WRONG_FEATURES,
        PolicyError::WrongLayerCount { .. } => LT_ERR_WRONG_LAYER_COUNT,
        PolicyError::WrongShape { .. } => LT_ERR_WRONG_SHAPE,
        PolicyError::WrongArrayLength { .. } => LT_ERR_WRONG_ARRAY_LENGTH,
        PolicyError::WrongActivation { .. } => LT_ERR_WRONG_ACTIVATION,
        PolicyError::BadScale { .. } => LT_ERR_INT8_BAD_SCALE,
        PolicyError::TooWideForInt8 { .. } => LT_ERR_INT8_TOO_WIDE,
    }
}

/// The code of a refused guidance step.
pub fn guidance_error_code(error: &GuidanceError) -> lt_status {
    match error {
        GuidanceError::Input(FeatureError::State(StateError::NonFinite)) => LT_ERR_INPUT_NON_FINITE_STATE,
        GuidanceError::Input(FeatureError::State(StateError::ZeroRadius)) => LT_ERR_INPUT_ZERO_RADIUS,
        GuidanceError::Input(FeatureError::State(StateError::NonPositiveMass)) => LT_ERR_INPUT_NON_POSITIVE_MASS,
        GuidanceError::Input(FeatureError::Target) => LT_ERR_INPUT_TARGET,
        GuidanceError::Input(FeatureError::TimeToGo) => LT_ERR_INPUT_TIME_TO_GO,
        GuidanceError::Input(FeatureError::NoOrbitPlane) => LT_ERR_INPUT_NO_ORBIT_PLANE,
        GuidanceError::NonFiniteAction => LT_ERR_NON_FINITE_ACTION,
    }
}
