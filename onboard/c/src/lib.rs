//! The onboard controller behind a C interface, for flight software written in C or C++ (a cFS
//! application, an F Prime component): `liblowthrust.a` and `include/lowthrust.h`.
//!
//! - `lt_version`: the library version and the blob format version it reads.
//! - `lt_transfer_load`, `lt_rendezvous_load`: check a weight blob and view it in place as a
//!   policy, in a caller-provided `lt_policy` (no heap). The policy borrows the blob's bytes:
//!   they must stay valid and unchanged for as long as the policy is used.
//! - `lt_transfer_step`, `lt_rendezvous_step`: one guidance cycle, navigation state in,
//!   thrust command out; the very functions the Rust SIL and the ground evaluation call
//!   (`onboard::guidance`), so the commands are the same bits.
//! - `lt_transfer_lookahead_step`, `lt_rendezvous_lookahead_step`: the same cycle with rollout
//!   lookahead (`onboard::lookahead`): candidate commands around the network's flown to the
//!   arrival with the onboard propagator, the cheapest predicted arrival commanded;
//!   `lt_lookahead_defaults` fills its settings.
//! - `lt_transfer_terminal_step`, `lt_rendezvous_terminal_step`: the same cycle with terminal
//!   targeting (`onboard::terminal`): over the last cycles the remaining commands are solved for
//!   the arrival; `lt_terminal_defaults` fills its settings.
//! - `lt_policy_describe`, `lt_error_name`: what a policy flies, and a name for each code.
//!
//! **No panic crosses the boundary.** Every entry point checks its pointers (null, the policy's
//! alignment) and lengths, and returns a code (`error`): 0, or one distinct negative code per
//! refusal. The crate is linted like `onboard` (no unwrap, no indexing, no panic), and the
//! static library is built with `panic = "abort"` (the `c-release` profile) as a backstop.
//! On a bare-metal target the crate is `no_std` with its own panic handler, a trap
//! into the flight software's fault handler; on a hosted target std provides it, so the rlib
//! also links into Rust tests and tools.
//!
//! **Failure means thrust off.** A step that returns an error has written the thrust-off
//! command (throttle 0) to its output, so a caller that forgets to check the code still does not
//! fly garbage. A refused load leaves the policy not loaded, even if it held a policy before.
//!
//! Units are the onboard crate's canonical ones: AU, AU per t* (t* = sqrt(AU^3 / mu_sun), about
//! 58.1 days; a 14-day guidance cycle is 0.2408 t*), the initial mass m0 = 1; the time to go in
//! t*. The command's direction is in the local polar frame (radial, along-track).
//!
//! # Example
//!
//! A blob that does not check out is refused with a code, and a step of the policy that was
//! not loaded commands thrust off, as flight software in safe mode would fly it:
//!
//! ```
//! use lowthrust::*;
//!
//! let mut policy = lt_policy::default();
//! let not_a_blob = [0u8; 64];
//! // SAFETY: each pointer is valid for its type and length.
//! let status = unsafe { lt_transfer_load(&mut policy, not_a_blob.as_ptr(), not_a_blob.len()) };
//! assert_ne!(status, LT_OK);
//! assert!((status as i32) < 0, "refused with a negative code: {}", status as i32);
//!
//! let navigation = lt_navigation_state { r: [1.0, 0.0], v: [0.0, 1.0], m: 1.0 };
//! let mars = lt_target_orbit { a: 1.524, e: 0.0, omega: 0.0 };
//! let mut command = lt_thrust_command { throttle: 1.0, alpha_r: 0.0, alpha_theta: 1.0 };
//! // SAFETY: as above; the policy is all zero (never loaded), which the step refuses.
//! let status = unsafe { lt_transfer_step(&policy, &navigation, &mars, 5.0, &mut command) };
//! assert_eq!(status, LT_ERR_NOT_LOADED);
//! assert_eq!(command.throttle, 0.0); // thrust off
//! ```
#![no_std]
#![deny(missing_docs)]
#![deny(clippy::undocumented_unsafe_blocks)]
// As in onboard: panic-freedom is enforced by the linter (CI runs clippy with -D warnings).
#![cfg_attr(
    not(test),
    deny(
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic,
        clippy::indexing_slicing,
        clippy::unreachable,
        clippy::integer_division,
        clippy::panic_in_result_fn
    )
)]
// C names for C types: the header is what flight software reads.
#![allow(non_camel_case_types)]

// A hosted build (the rlib in Rust tests and tools, the host static library) gets the panic
// handler from std; a bare-metal build defines its own below.
#[cfg(not(target_os = "none"))]
extern crate std;

pub mod error;

use core::ffi::c_char;
use core::mem::{align_of, size_of};
use core::ptr;

use onboard::dynamics::{SpacecraftState, ThrustCommand};
use onboard::geometry::Dimension;
use onboard::guidance::{
    rendezvous3_step, rendezvous_step, transfer3_step, transfer_step, Actor, Aim, GuidanceError, TargetOrbit3,
};
use onboard::lookahead::{lookahead_step, Decision, LookaheadSettings, Prediction};
use onboard::policy::{Rendezvous3Policy, RendezvousPolicy, Transfer3Policy, TransferPolicy};
use onboard::spatial::{RtnCommand, SpatialCraftState};
use onboard::terminal::{terminal_step, TerminalDecision, TerminalSettings};
use shared::blob::{FeatureLayout, Quantization, FORMAT_VERSION};
use shared::orbit::{CartesianState, OrbitPlane, OrbitShape, SpatialState};
use shared::spacecraft::CanonicalSpacecraft;

pub use error::*;

/// Words of `lt_policy`'s storage: room for either network's layer views on 32- and 64-bit
/// targets, with headroom so the handle's size (part of the ABI) need not change with them.
pub const LT_POLICY_STORAGE_WORDS: usize = 48;

/// `lt_policy_info::problem`: a transfer (reach an orbit).
pub const LT_PROBLEM_TRANSFER: u32 = 0;
/// `lt_policy_info::problem`: a rendezvous (meet a body).
pub const LT_PROBLEM_RENDEZVOUS: u32 = 1;
/// `lt_policy_info::problem`: a transfer in three dimensions (an inclined target orbit).
pub const LT_PROBLEM_TRANSFER3: u32 = 2;
/// `lt_policy_info::problem`: a rendezvous in three dimensions.
pub const LT_PROBLEM_RENDEZVOUS3: u32 = 3;
/// `lt_policy_info::quantization`: f32 weights.
pub const LT_QUANTIZATION_F32: u32 = 0;
/// `lt_policy_info::quantization`: int8 weights, 16-bit activations.
pub const LT_QUANTIZATION_INT8: u32 = 1;

/// A loaded policy, in storage the caller provides (a static, a member of the application's
/// state): fixed size, 8-byte aligned, no heap. All-zero storage (a zero-initialized static) is
/// a policy not loaded yet. It holds views into the blob, never a copy of it: the blob's bytes
/// must outlive every use of the policy. A loaded policy may be copied; it owns nothing.
#[repr(C)]
pub struct lt_policy {
    /// Opaque: written by `lt_*_load`, read by the steps.
    opaque: [u64; LT_POLICY_STORAGE_WORDS],
}

/// Not loaded: the state of zeroed storage.
impl Default for lt_policy {
    fn default() -> Self {
        Self {
            opaque: [0; LT_POLICY_STORAGE_WORDS],
        }
    }
}

/// Library and blob format versions.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct lt_version_info {
    /// Library version, major.
    pub major: u16,
    /// Library version, minor.
    pub minor: u16,
    /// Library version, patch.
    pub patch: u16,
    /// The weight-blob format version the loads accept (any other is refused).
    pub blob_format_version: u16,
}

/// What a loaded policy flies, and the mission its blob carries (family 0: any family of the
/// thesis's 14-day cycles, AU and the Sun's time unit).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct lt_policy_info {
    /// `LT_PROBLEM_TRANSFER` or `LT_PROBLEM_RENDEZVOUS` (planar), `LT_PROBLEM_TRANSFER3` or
    /// `LT_PROBLEM_RENDEZVOUS3` (three dimensions).
    pub problem: u32,
    /// `LT_QUANTIZATION_F32` or `LT_QUANTIZATION_INT8`.
    pub quantization: u32,
    /// The guidance cycle the network was trained for (t*), for `lt_lookahead_settings.cycle` and
    /// `lt_terminal_settings.cycle`; 0 when its family cuts flights of different lengths into a
    /// count of cycles each (the flight software knows the length).
    pub cycle: f64,
    /// The canonical length unit of its features and states, m.
    pub length_unit_m: f64,
    /// The canonical time unit, s.
    pub time_unit_s: f64,
    /// The mission family's fingerprint (0: any family of the thesis's units and cycle, as the
    /// blobs made before the mission was carried are upgraded).
    pub family: u32,
}

/// The navigation state: position (AU), velocity (AU/t*), mass (m0 = 1), in the ecliptic plane.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct lt_navigation_state {
    /// Position x, y (AU).
    pub r: [f64; 2],
    /// Velocity x, y (AU/t*).
    pub v: [f64; 2],
    /// Mass (fraction of the initial mass).
    pub m: f64,
}

/// A transfer's target orbit (reached anywhere on it).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct lt_target_orbit {
    /// Semi-major axis (AU), > 0.
    pub a: f64,
    /// Eccentricity, in [0, 1).
    pub e: f64,
    /// Argument of periapsis (rad).
    pub omega: f64,
}

/// A rendezvous target body's state now.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct lt_body_state {
    /// Position x, y (AU).
    pub r: [f64; 2],
    /// Velocity x, y (AU/t*).
    pub v: [f64; 2],
}

/// A thrust command, held for the guidance cycle.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct lt_thrust_command {
    /// Throttle in [0, 1]; 0 is thrust off.
    pub throttle: f64,
    /// Radial component of the unit thrust direction.
    pub alpha_r: f64,
    /// Along-track component of the unit thrust direction.
    pub alpha_theta: f64,
}

impl From<ThrustCommand> for lt_thrust_command {
    fn from(c: ThrustCommand) -> Self {
        Self {
            throttle: c.throttle,
            alpha_r: c.alpha_r,
            alpha_theta: c.alpha_theta,
        }
    }
}

impl From<lt_navigation_state> for SpacecraftState {
    fn from(s: lt_navigation_state) -> Self {
        Self { r: s.r, v: s.v, m: s.m }
    }
}

impl From<lt_target_orbit> for OrbitShape {
    fn from(t: lt_target_orbit) -> Self {
        Self {
            a: t.a,
            e: t.e,
            omega: t.omega,
        }
    }
}

impl From<lt_body_state> for CartesianState {
    fn from(b: lt_body_state) -> Self {
        Self { r: b.r, v: b.v }
    }
}

/// The navigation state in three dimensions: position (length units), velocity, mass (m0 = 1),
/// in the inertial frame the target's elements are given in.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct lt_navigation_state3 {
    /// Position x, y, z.
    pub r: [f64; 3],
    /// Velocity x, y, z.
    pub v: [f64; 3],
    /// Mass (fraction of the initial mass).
    pub m: f64,
}

/// A transfer's target orbit in three dimensions (reached anywhere on it): its shape in its
/// plane, and the plane.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct lt_target_orbit3 {
    /// Semi-major axis, > 0.
    pub a: f64,
    /// Eccentricity, in [0, 1).
    pub e: f64,
    /// Argument of periapsis from the ascending node (rad).
    pub omega: f64,
    /// Inclination to the xy-plane (rad), in [0, pi].
    pub inclination: f64,
    /// Right ascension of the ascending node (rad).
    pub raan: f64,
}

/// A rendezvous target body's state now, in three dimensions.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct lt_body_state3 {
    /// Position x, y, z.
    pub r: [f64; 3],
    /// Velocity x, y, z.
    pub v: [f64; 3],
}

/// A thrust command in three dimensions, held for the guidance cycle in the local RTN frame
/// (radial; transverse, in the orbit plane ahead of the radius; normal, along the angular
/// momentum).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct lt_rtn_command {
    /// Throttle in [0, 1]; 0 is thrust off.
    pub throttle: f64,
    /// Radial component of the unit thrust direction.
    pub radial: f64,
    /// Transverse component.
    pub transverse: f64,
    /// Normal component.
    pub normal: f64,
}

impl From<RtnCommand> for lt_rtn_command {
    fn from(c: RtnCommand) -> Self {
        Self {
            throttle: c.throttle,
            radial: c.radial,
            transverse: c.transverse,
            normal: c.normal,
        }
    }
}

impl From<lt_navigation_state3> for SpatialCraftState {
    fn from(s: lt_navigation_state3) -> Self {
        Self {
            orbit: SpatialState { r: s.r, v: s.v },
            m: s.m,
        }
    }
}

impl From<lt_target_orbit3> for TargetOrbit3 {
    fn from(t: lt_target_orbit3) -> Self {
        Self {
            shape: OrbitShape {
                a: t.a,
                e: t.e,
                omega: t.omega,
            },
            plane: OrbitPlane {
                inclination: t.inclination,
                raan: t.raan,
            },
        }
    }
}

impl From<lt_body_state3> for SpatialState {
    fn from(b: lt_body_state3) -> Self {
        Self { r: b.r, v: b.v }
    }
}

/// The thrust-off command every failed three-dimensional step writes (`onboard`'s
/// `RtnCommand::OFF`).
pub const RTN_THRUST_OFF: lt_rtn_command = lt_rtn_command {
    throttle: 0.0,
    radial: 0.0,
    transverse: 1.0,
    normal: 0.0,
};

/// The thrust-off command every failed step writes (`onboard`'s `ThrustCommand::OFF`).
pub const THRUST_OFF: lt_thrust_command = lt_thrust_command {
    throttle: 0.0,
    alpha_r: 0.0,
    alpha_theta: 1.0,
};

/// What the storage of a loaded `lt_policy` holds. The marker comes first (`repr(C)`), so a
/// policy not loaded (zeroed, or refused) is told apart by reading one aligned word.
#[repr(C)]
struct Loaded {
    marker: u64,
    network: Network,
}

enum Network {
    // 'static stands for the caller's promise that the blob outlives the policy.
    Transfer(TransferPolicy<'static>),
    Rendezvous(RendezvousPolicy<'static>),
    Transfer3(Transfer3Policy<'static>),
    Rendezvous3(Rendezvous3Policy<'static>),
}

/// "LTPOLICY": the storage holds a `Loaded`.
const LOADED_MARKER: u64 = u64::from_le_bytes(*b"LTPOLICY");

// The handle's size is fixed in the header; the build fails on a target where it is too small.
const _: () = assert!(size_of::<Loaded>() <= size_of::<lt_policy>());
const _: () = assert!(align_of::<Loaded>() <= align_of::<lt_policy>());

const fn version_part(s: &str) -> u16 {
    let mut value = 0u16;
    let mut rest = s.as_bytes();
    while let [byte, tail @ ..] = rest {
        // Cargo's version parts are decimal; a non-digit could only be a pre-release tag.
        if byte.is_ascii_digit() {
            value = value.saturating_mul(10).saturating_add((*byte - b'0') as u16);
        }
        rest = tail;
    }
    value
}

/// This library's version (the crate's) and the blob format version it reads.
pub const VERSION: lt_version_info = lt_version_info {
    major: version_part(env!("CARGO_PKG_VERSION_MAJOR")),
    minor: version_part(env!("CARGO_PKG_VERSION_MINOR")),
    patch: version_part(env!("CARGO_PKG_VERSION_PATCH")),
    blob_format_version: FORMAT_VERSION,
};

/// Writes the library version and the blob format version it reads to `*out`.
/// Returns `LT_OK`, or `LT_ERR_NULL_POINTER`.
///
/// # Safety
/// `out` is null or valid for writing an `lt_version_info` (any alignment).
#[no_mangle]
pub unsafe extern "C" fn lt_version(out: *mut lt_version_info) -> lt_status {
    if out.is_null() {
        return LT_ERR_NULL_POINTER;
    }
    // SAFETY: non-null, and the caller promises it is writable; unaligned writes are allowed.
    unsafe { ptr::write_unaligned(out, VERSION) };
    LT_OK
}

/// The name of a return code, e.g. `"blob_crc_mismatch"`, for logs and event messages: a static
/// NUL-terminated string, `"unknown"` for a value that is not a code. Never null.
#[no_mangle]
pub extern "C" fn lt_error_name(code: i32) -> *const c_char {
    error_name(code).as_ptr()
}

/// Checks the policy pointer: non-null and aligned for `Loaded`.
fn policy_storage(policy: *const lt_policy) -> Result<*const lt_policy, lt_status> {
    if policy.is_null() {
        Err(LT_ERR_NULL_POINTER)
    } else if !policy.cast::<Loaded>().is_aligned() {
        Err(LT_ERR_MISALIGNED_POLICY)
    } else {
        Ok(policy)
    }
}

/// The blob as a slice, after the checks `slice::from_raw_parts` requires of its arguments
/// (non-null, a length that fits `isize` and does not wrap the address space).
///
/// # Safety
/// `blob` is null or valid for reading `len` bytes, unchanged for as long as the returned
/// slice (and any policy made from it) is used.
unsafe fn blob_bytes(blob: *const u8, len: usize) -> Result<&'static [u8], lt_status> {
    if blob.is_null() {
        return Err(LT_ERR_NULL_POINTER);
    }
    if isize::try_from(len).is_err() || (blob as usize).checked_add(len).is_none() {
        return Err(LT_ERR_BLOB_LENGTH);
    }
    // SAFETY: non-null, length in range and not wrapping (checked above); readable and left
    // unchanged for the policy's life by the caller's contract. u8 needs no alignment.
    Ok(unsafe { core::slice::from_raw_parts(blob, len) })
}

/// # Safety
/// As `lt_transfer_load`.
unsafe fn load(policy: *mut lt_policy, blob: *const u8, blob_len: usize, features: FeatureLayout) -> lt_status {
    let storage = match policy_storage(policy) {
        Ok(_) => policy.cast::<Loaded>(),
        Err(code) => return code,
    };
    // Not loaded until this load succeeds: a refused blob never leaves an older network flying.
    // SAFETY: non-null and aligned (checked), writable by the caller's contract; the marker
    // is the first word of the storage.
    unsafe { ptr::write(storage.cast::<u64>(), 0) };
    // SAFETY: the caller's contract on `blob`, passed on.
    let bytes = match unsafe { blob_bytes(blob, blob_len) } {
        Ok(bytes) => bytes,
        Err(code) => return code,
    };
    let kind = features.problem();
    let network = match features {
        FeatureLayout::TransferPolar10 => TransferPolicy::from_bytes(bytes, kind).map(Network::Transfer),
        FeatureLayout::RendezvousPolar22 => RendezvousPolicy::from_bytes(bytes, kind).map(Network::Rendezvous),
        FeatureLayout::TransferSpatial15 => Transfer3Policy::from_bytes(bytes, kind).map(Network::Transfer3),
        FeatureLayout::RendezvousSpatial30 => Rendezvous3Policy::from_bytes(bytes, kind).map(Network::Rendezvous3),
    };
    match network {
        Ok(network) => {
            let loaded = Loaded {
                marker: LOADED_MARKER,
                network,
            };
            // SAFETY: non-null, aligned for `Loaded` (checked), large enough (const assert), and
            // writable by the caller's contract. Its old contents are plain data, never dropped.
            unsafe { ptr::write(storage, loaded) };
            LT_OK
        }
        Err(error) => policy_error_code(&error),
    }
}

/// Checks a transfer weight blob (magic, format version, CRC-32, structure, the 10-256-256-3
/// shape) and makes `*policy` a view of it. Nothing is copied: `blob` must stay valid and
/// unchanged while the policy is used (a blob in flash, or a buffer the application keeps).
///
/// Returns `LT_OK`, or the refusal's code (`LT_ERR_BLOB_*` for the bytes, `LT_ERR_WRONG_*` and
/// `LT_ERR_INT8_*` for a network this controller cannot fly, `LT_ERR_NULL_POINTER`,
/// `LT_ERR_MISALIGNED_POLICY`, `LT_ERR_BLOB_LENGTH`). On refusal `*policy` (if writable) is not
/// loaded, whatever it held: fly thrust off (safe mode). To replace a flying policy, load the
/// new blob into a second `lt_policy` and switch on `LT_OK`.
///
/// # Safety
/// `policy` is null or valid for writing an `lt_policy`; `blob` is null or valid for reading
/// `blob_len` bytes, unchanged for as long as the policy is used.
#[no_mangle]
pub unsafe extern "C" fn lt_transfer_load(policy: *mut lt_policy, blob: *const u8, blob_len: usize) -> lt_status {
    // SAFETY: the caller's contract, passed on.
    unsafe { load(policy, blob, blob_len, FeatureLayout::TransferPolar10) }
}

/// `lt_transfer_load` for a rendezvous blob (22-256-256-3).
///
/// # Safety
/// As `lt_transfer_load`.
#[no_mangle]
pub unsafe extern "C" fn lt_rendezvous_load(policy: *mut lt_policy, blob: *const u8, blob_len: usize) -> lt_status {
    // SAFETY: the caller's contract, passed on.
    unsafe { load(policy, blob, blob_len, FeatureLayout::RendezvousPolar22) }
}

/// `lt_transfer_load` for a three-dimensional transfer blob (15-256-256-4: the 15 features of an
/// inclined target orbit, throttle and an RTN direction out).
///
/// # Safety
/// As `lt_transfer_load`.
#[no_mangle]
pub unsafe extern "C" fn lt_transfer3_load(policy: *mut lt_policy, blob: *const u8, blob_len: usize) -> lt_status {
    // SAFETY: the caller's contract, passed on.
    unsafe { load(policy, blob, blob_len, FeatureLayout::TransferSpatial15) }
}

/// `lt_transfer_load` for a three-dimensional rendezvous blob (30-256-256-4).
///
/// # Safety
/// As `lt_transfer_load`.
#[no_mangle]
pub unsafe extern "C" fn lt_rendezvous3_load(policy: *mut lt_policy, blob: *const u8, blob_len: usize) -> lt_status {
    // SAFETY: the caller's contract, passed on.
    unsafe { load(policy, blob, blob_len, FeatureLayout::RendezvousSpatial30) }
}

/// The loaded network behind `policy`.
///
/// # Safety
/// `policy` is null or valid for reading an `lt_policy` that is all zero or was written by a
/// load, and the blob of a loaded policy is still valid.
unsafe fn loaded<'p>(policy: *const lt_policy) -> Result<&'p Network, lt_status> {
    let storage = policy_storage(policy)?.cast::<Loaded>();
    // SAFETY: non-null and aligned (checked), readable by the caller's contract.
    let marker = unsafe { ptr::read(storage.cast::<u64>()) };
    if marker != LOADED_MARKER {
        return Err(LT_ERR_NOT_LOADED);
    }
    // SAFETY: the marker is written only together with a whole `Loaded` (in `load`), and cleared
    // first by every load, so the storage holds a valid `Loaded`.
    Ok(unsafe { &(*storage).network })
}

/// Reads an input struct (any alignment).
///
/// # Safety
/// `p` is null or valid for reading a `T`.
unsafe fn read_input<T: Copy>(p: *const T) -> Result<T, lt_status> {
    if p.is_null() {
        return Err(LT_ERR_NULL_POINTER);
    }
    // SAFETY: non-null and readable by the caller's contract; read unaligned, so any address is
    // fine, and copied before any output is written (inputs and output may overlap).
    Ok(unsafe { ptr::read_unaligned(p) })
}

/// Writes the outcome of a step: the command, or thrust off with the error's code.
///
/// # Safety
/// `command` is null or valid for writing an `lt_thrust_command`.
unsafe fn finish(command: *mut lt_thrust_command, result: Result<lt_thrust_command, lt_status>) -> lt_status {
    let (out, code) = match result {
        Ok(c) => (c, LT_OK),
        Err(code) => (THRUST_OFF, code),
    };
    if command.is_null() {
        return LT_ERR_NULL_POINTER;
    }
    // SAFETY: non-null and writable by the caller's contract; unaligned writes are allowed.
    unsafe { ptr::write_unaligned(command, out) };
    code
}

fn guided(result: Result<ThrustCommand, GuidanceError>) -> Result<lt_thrust_command, lt_status> {
    result.map(lt_thrust_command::from).map_err(|e| guidance_error_code(&e))
}

/// One transfer guidance cycle: the command to hold until the next cycle, from the navigation
/// state, the target orbit and the time to go (t*, >= 0), through `onboard::guidance::
/// transfer_step` (features, network, action decoding).
///
/// Returns `LT_OK` with the command in `*command`; or a code, with thrust off (throttle 0) in
/// `*command`: `LT_ERR_INPUT_*` (navigation, target or time to go refused),
/// `LT_ERR_NON_FINITE_ACTION`, `LT_ERR_NOT_LOADED`, `LT_ERR_WRONG_POLICY_KIND`,
/// `LT_ERR_NULL_POINTER`, `LT_ERR_MISALIGNED_POLICY`. On any error the caller commands thrust
/// off for the cycle.
///
/// # Safety
/// Each pointer is null or valid for its struct (inputs read, `command` written; any alignment
/// except `policy`'s, which must be all zero or written by a load, with its blob still valid).
#[no_mangle]
pub unsafe extern "C" fn lt_transfer_step(
    policy: *const lt_policy,
    navigation: *const lt_navigation_state,
    target: *const lt_target_orbit,
    time_to_go: f64,
    command: *mut lt_thrust_command,
) -> lt_status {
    // SAFETY: the caller's contract on each pointer, passed on.
    unsafe {
        let result = transfer(policy, navigation, target, time_to_go);
        finish(command, result)
    }
}

/// # Safety
/// As `lt_transfer_step`.
unsafe fn transfer(
    policy: *const lt_policy,
    navigation: *const lt_navigation_state,
    target: *const lt_target_orbit,
    time_to_go: f64,
) -> Result<lt_thrust_command, lt_status> {
    // SAFETY: the caller's contract on each pointer, passed on.
    let (network, navigation, target) = unsafe { (loaded(policy)?, read_input(navigation)?, read_input(target)?) };
    let Network::Transfer(actor) = network else {
        return Err(LT_ERR_WRONG_POLICY_KIND);
    };
    guided(transfer_step(actor, &navigation.into(), &target.into(), time_to_go))
}

/// One rendezvous guidance cycle: as `lt_transfer_step`, with the target body's state now
/// (propagated by the caller to this cycle's epoch) instead of an orbit.
///
/// # Safety
/// As `lt_transfer_step`.
#[no_mangle]
pub unsafe extern "C" fn lt_rendezvous_step(
    policy: *const lt_policy,
    navigation: *const lt_navigation_state,
    body: *const lt_body_state,
    time_to_go: f64,
    command: *mut lt_thrust_command,
) -> lt_status {
    // SAFETY: the caller's contract on each pointer, passed on.
    unsafe {
        let result = rendezvous(policy, navigation, body, time_to_go);
        finish(command, result)
    }
}

/// # Safety
/// As `lt_transfer_step`.
unsafe fn rendezvous(
    policy: *const lt_policy,
    navigation: *const lt_navigation_state,
    body: *const lt_body_state,
    time_to_go: f64,
) -> Result<lt_thrust_command, lt_status> {
    // SAFETY: the caller's contract on each pointer, passed on.
    let (network, navigation, body) = unsafe { (loaded(policy)?, read_input(navigation)?, read_input(body)?) };
    let Network::Rendezvous(actor) = network else {
        return Err(LT_ERR_WRONG_POLICY_KIND);
    };
    guided(rendezvous_step(actor, &navigation.into(), &body.into(), time_to_go))
}

/// Writes the outcome of a three-dimensional step: the command, or thrust off with the error's
/// code.
///
/// # Safety
/// `command` is null or valid for writing an `lt_rtn_command`.
unsafe fn finish3(command: *mut lt_rtn_command, result: Result<RtnCommand, lt_status>) -> lt_status {
    let (out, code) = match result {
        Ok(c) => (c.into(), LT_OK),
        Err(code) => (RTN_THRUST_OFF, code),
    };
    if command.is_null() {
        return LT_ERR_NULL_POINTER;
    }
    // SAFETY: non-null and writable by the caller's contract; unaligned writes are allowed.
    unsafe { ptr::write_unaligned(command, out) };
    code
}

/// One three-dimensional transfer guidance cycle: the RTN command to hold until the next cycle,
/// from the navigation state, the target orbit (shape and plane) and the time to go (t*, >= 0),
/// through `onboard::guidance::transfer3_step`. Returns and writes as `lt_transfer_step` (a
/// state whose velocity lies along its radius has no orbit plane: `LT_ERR_INPUT_NO_ORBIT_PLANE`);
/// a planar policy is `LT_ERR_WRONG_POLICY_KIND`.
///
/// # Safety
/// As `lt_transfer_step`, with `command` null or valid for writing an `lt_rtn_command`.
#[no_mangle]
pub unsafe extern "C" fn lt_transfer3_step(
    policy: *const lt_policy,
    navigation: *const lt_navigation_state3,
    target: *const lt_target_orbit3,
    time_to_go: f64,
    command: *mut lt_rtn_command,
) -> lt_status {
    // SAFETY: the caller's contract on each pointer, passed on.
    let inputs = unsafe { (loaded(policy), read_input(navigation), read_input(target)) };
    let result = match inputs {
        (Ok(Network::Transfer3(actor)), Ok(navigation), Ok(target)) => {
            transfer3_step(actor, &navigation.into(), &target.into(), time_to_go).map_err(|e| guidance_error_code(&e))
        }
        (Err(code), _, _) | (_, Err(code), _) | (_, _, Err(code)) => Err(code),
        (Ok(_), _, _) => Err(LT_ERR_WRONG_POLICY_KIND),
    };
    // SAFETY: the caller's contract on `command`, passed on.
    unsafe { finish3(command, result) }
}

/// One three-dimensional rendezvous guidance cycle: as `lt_transfer3_step`, with the target
/// body's state now (propagated by the caller to this cycle's epoch) instead of an orbit.
///
/// # Safety
/// As `lt_transfer3_step`.
#[no_mangle]
pub unsafe extern "C" fn lt_rendezvous3_step(
    policy: *const lt_policy,
    navigation: *const lt_navigation_state3,
    body: *const lt_body_state3,
    time_to_go: f64,
    command: *mut lt_rtn_command,
) -> lt_status {
    // SAFETY: the caller's contract on each pointer, passed on.
    let inputs = unsafe { (loaded(policy), read_input(navigation), read_input(body)) };
    let result = match inputs {
        (Ok(Network::Rendezvous3(actor)), Ok(navigation), Ok(body)) => {
            rendezvous3_step(actor, &navigation.into(), &body.into(), time_to_go).map_err(|e| guidance_error_code(&e))
        }
        (Err(code), _, _) | (_, Err(code), _) | (_, _, Err(code)) => Err(code),
        (Ok(_), _, _) => Err(LT_ERR_WRONG_POLICY_KIND),
    };
    // SAFETY: the caller's contract on `command`, passed on.
    unsafe { finish3(command, result) }
}

/// The nominal spacecraft the lookahead's rollouts fly, in canonical units.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct lt_spacecraft {
    /// Maximum thrust over the initial mass (m0 AU / t*^2).
    pub thrust: f64,
    /// Exhaust speed g0 Isp (AU / t*).
    pub exhaust_speed: f64,
}

/// What the lookahead weighs (`lt_lookahead_defaults` fills the defaults).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct lt_lookahead_settings {
    /// Position residual counted as one unit of miss (AU); default 0.01.
    pub goal_position: f64,
    /// Velocity residual counted as one unit of miss (AU/t*); default 0.01.
    pub goal_velocity: f64,
    /// Below this many goal units a smaller predicted miss is worth nothing more; default 0.5.
    pub accuracy_floor: f64,
    /// Goal units one initial mass of propellant is worth; default 5.
    pub fuel_weight: f64,
    /// Fraction of the thrust the rollouts plan without, in [0, 1) (a duty-cycle margin against
    /// missed thrust); default 0.
    pub thrust_margin: f64,
    /// Length of a guidance cycle (t*); default 14 days, 0.240829... (the scenario family's).
    pub cycle: f64,
    /// Most cycles a rollout flies; with more left the network's command is flown unexamined.
    pub max_cycles: u32,
    /// Whole cycles before the arrival at which the rollouts are judged (the target met early
    /// and followed, the last cycles kept in reserve); default 0.
    pub arrival_margin: u32,
    /// Most rollout steps a guidance cycle flies in all (each rollout cycle counts its fixed
    /// DOP853 steps, one from a periapsis beyond 0.68 AU), the most useful candidates first;
    /// 0 (default): no limit.
    pub rollout_budget: u32,
}

/// What one lookahead cycle decided, for telemetry.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct lt_lookahead_report {
    /// The network's own command.
    pub network: lt_thrust_command,
    /// The candidate commanded (0: the network's).
    pub chosen: u32,
    /// 1 when the predicted arrival below is valid (a rollout flew), else 0.
    pub predicted_valid: u32,
    /// Predicted position residual at the arrival (AU).
    pub predicted_position: f64,
    /// Predicted velocity residual at the arrival (AU/t*).
    pub predicted_velocity: f64,
    /// Predicted mass at the arrival (m0 = 1).
    pub predicted_mass: f64,
    /// The predicted arrival's cost (goal units).
    pub predicted_cost: f64,
}

/// What one three-dimensional lookahead cycle decided, for telemetry: as `lt_lookahead_report`,
/// with the network's RTN command.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct lt_lookahead_report3 {
    /// The network's own command.
    pub network: lt_rtn_command,
    /// The candidate commanded (0: the network's).
    pub chosen: u32,
    /// 1 when the predicted arrival below is valid (a rollout flew), else 0.
    pub predicted_valid: u32,
    /// Predicted position residual at the arrival (AU).
    pub predicted_position: f64,
    /// Predicted velocity residual at the arrival (AU/t*).
    pub predicted_velocity: f64,
    /// Predicted mass at the arrival (m0 = 1).
    pub predicted_mass: f64,
    /// The predicted arrival's cost (goal units).
    pub predicted_cost: f64,
}

impl From<lt_lookahead_settings> for LookaheadSettings {
    fn from(s: lt_lookahead_settings) -> Self {
        Self {
            goal_position: s.goal_position,
            goal_velocity: s.goal_velocity,
            accuracy_floor: s.accuracy_floor,
            fuel_weight: s.fuel_weight,
            max_cycles: s.max_cycles,
            thrust_margin: s.thrust_margin,
            arrival_margin: s.arrival_margin,
            rollout_budget: s.rollout_budget,
            cycle: s.cycle,
            ..Self::default()
        }
    }
}

/// Writes the default lookahead settings to `*out`. Returns `LT_OK`, or `LT_ERR_NULL_POINTER`.
///
/// # Safety
/// `out` is null or valid for writing an `lt_lookahead_settings` (any alignment).
#[no_mangle]
pub unsafe extern "C" fn lt_lookahead_defaults(out: *mut lt_lookahead_settings) -> lt_status {
    if out.is_null() {
        return LT_ERR_NULL_POINTER;
    }
    let d = LookaheadSettings::default();
    let settings = lt_lookahead_settings {
        goal_position: d.goal_position,
        goal_velocity: d.goal_velocity,
        accuracy_floor: d.accuracy_floor,
        fuel_weight: d.fuel_weight,
        max_cycles: d.max_cycles,
        thrust_margin: d.thrust_margin,
        arrival_margin: d.arrival_margin,
        rollout_budget: d.rollout_budget,
        cycle: d.cycle,
    };
    // SAFETY: non-null and writable by the caller's contract; unaligned writes are allowed.
    unsafe { ptr::write_unaligned(out, settings) };
    LT_OK
}

impl From<lt_spacecraft> for CanonicalSpacecraft {
    fn from(s: lt_spacecraft) -> Self {
        Self {
            thrust: s.thrust,
            exhaust_speed: s.exhaust_speed,
        }
    }
}

/// An onboard aid's spacecraft and settings (lookahead, terminal targeting), read and checked:
/// `refused` when the spacecraft is not valid or `usable` refuses the settings.
///
/// # Safety
/// Each pointer is null or valid for reading its struct.
unsafe fn aid_inputs<C: Copy, S: From<C>>(
    spacecraft: *const lt_spacecraft,
    settings: *const C,
    usable: impl FnOnce(&S) -> bool,
    refused: lt_status,
) -> Result<(CanonicalSpacecraft, S), lt_status> {
    // SAFETY: the caller's contract on each pointer, passed on.
    let (spacecraft, settings) = unsafe { (read_input(spacecraft)?, read_input(settings)?) };
    let (spacecraft, settings) = (CanonicalSpacecraft::from(spacecraft), S::from(settings));
    if !spacecraft.is_valid() || !usable(&settings) {
        return Err(refused);
    }
    Ok((spacecraft, settings))
}

/// The lookahead's spacecraft and settings, checked.
///
/// # Safety
/// Each pointer is null or valid for reading its struct.
unsafe fn lookahead_inputs(
    spacecraft: *const lt_spacecraft,
    settings: *const lt_lookahead_settings,
) -> Result<(CanonicalSpacecraft, LookaheadSettings), lt_status> {
    let usable = |s: &LookaheadSettings| s.validate().is_ok();
    // SAFETY: the caller's contract on each pointer, passed on.
    unsafe { aid_inputs(spacecraft, settings, usable, LT_ERR_INPUT_LOOKAHEAD) }
}

/// One lookahead cycle of `actor` towards `target`, in either dimension.
fn looked_ahead<const N: usize, const OUT: usize, A: Actor<N, OUT>, T: Aim<N, OUT>>(
    actor: &A,
    navigation: &<T::Geometry as Dimension>::State,
    target: &T,
    time_to_go: f64,
    inputs: (CanonicalSpacecraft, LookaheadSettings),
) -> Result<Decision<<T::Geometry as Dimension>::Command>, lt_status> {
    lookahead_step(actor, navigation, target, time_to_go, &inputs.0, &inputs.1).map_err(|e| guidance_error_code(&e))
}

/// A predicted arrival's telemetry fields: valid, position, velocity, mass, cost (NaN when none).
fn predicted_fields(p: Option<Prediction>) -> (u32, f64, f64, f64, f64) {
    (
        u32::from(p.is_some()),
        p.map_or(f64::NAN, |p| p.residuals.position),
        p.map_or(f64::NAN, |p| p.residuals.velocity),
        p.map_or(f64::NAN, |p| p.mass),
        p.map_or(f64::NAN, |p| p.cost),
    )
}

impl From<Decision<ThrustCommand>> for lt_lookahead_report {
    fn from(d: Decision<ThrustCommand>) -> Self {
        let (predicted_valid, predicted_position, predicted_velocity, predicted_mass, predicted_cost) =
            predicted_fields(d.predicted);
        Self {
            network: d.network.into(),
            chosen: u32::try_from(d.chosen).unwrap_or(u32::MAX),
            predicted_valid,
            predicted_position,
            predicted_velocity,
            predicted_mass,
            predicted_cost,
        }
    }
}

impl From<Decision<RtnCommand>> for lt_lookahead_report3 {
    fn from(d: Decision<RtnCommand>) -> Self {
        let (predicted_valid, predicted_position, predicted_velocity, predicted_mass, predicted_cost) =
            predicted_fields(d.predicted);
        Self {
            network: d.network.into(),
            chosen: u32::try_from(d.chosen).unwrap_or(u32::MAX),
            predicted_valid,
            predicted_position,
            predicted_velocity,
            predicted_mass,
            predicted_cost,
        }
    }
}

/// The lookahead report of a refused cycle: the thrust-off command, nothing predicted.
const LOOKAHEAD_REFUSED: lt_lookahead_report = lt_lookahead_report {
    network: THRUST_OFF,
    chosen: 0,
    predicted_valid: 0,
    predicted_position: f64::NAN,
    predicted_velocity: f64::NAN,
    predicted_mass: f64::NAN,
    predicted_cost: f64::NAN,
};

/// The three-dimensional lookahead report of a refused cycle.
const LOOKAHEAD3_REFUSED: lt_lookahead_report3 = lt_lookahead_report3 {
    network: RTN_THRUST_OFF,
    chosen: 0,
    predicted_valid: 0,
    predicted_position: f64::NAN,
    predicted_velocity: f64::NAN,
    predicted_mass: f64::NAN,
    predicted_cost: f64::NAN,
};

/// Writes an aided cycle's outcome, in either dimension: the command (`off`, thrust off, on
/// error) and, when `report` is not null, its report (`refused` on error).
///
/// # Safety
/// `command` and `report` are null or valid for writing their structs.
unsafe fn finish_with_report<C: Copy, R: Copy>(
    command: *mut C,
    report: *mut R,
    result: Result<(C, R), lt_status>,
    off: C,
    refused: R,
) -> lt_status {
    let written = result.map_or(refused, |(_, r)| r);
    if !report.is_null() {
        // SAFETY: non-null and writable by the caller's contract; unaligned writes are allowed.
        unsafe { ptr::write_unaligned(report, written) };
    }
    let (out, code) = match result {
        Ok((c, _)) => (c, LT_OK),
        Err(code) => (off, code),
    };
    if command.is_null() {
        return LT_ERR_NULL_POINTER;
    }
    // SAFETY: non-null and writable by the caller's contract; unaligned writes are allowed.
    unsafe { ptr::write_unaligned(command, out) };
    code
}

/// One transfer guidance cycle with rollout lookahead (`onboard::lookahead::lookahead_step`):
/// the network's command and 20 alternatives around it are each held for this cycle, the
/// network flies every later one with the onboard propagator and `spacecraft`, and the command
/// of the cheapest predicted arrival is returned. At most 21 x the cycles left rollout cycles, or
/// the settings' `rollout_budget` of steps: run it at the 14-day guidance rate, not in a fast loop.
///
/// Returns as `lt_transfer_step`, and `LT_ERR_INPUT_LOOKAHEAD` for an unusable spacecraft or
/// settings; `report` may be null, else it receives the decision (nothing predicted on error).
///
/// # Safety
/// As `lt_transfer_step`; `spacecraft` and `settings` are null or valid for reading their
/// structs, `report` null or valid for writing an `lt_lookahead_report`.
#[no_mangle]
#[allow(clippy::too_many_arguments)] // the C signature: one pointer per struct
pub unsafe extern "C" fn lt_transfer_lookahead_step(
    policy: *const lt_policy,
    navigation: *const lt_navigation_state,
    target: *const lt_target_orbit,
    time_to_go: f64,
    spacecraft: *const lt_spacecraft,
    settings: *const lt_lookahead_settings,
    command: *mut lt_thrust_command,
    report: *mut lt_lookahead_report,
) -> lt_status {
    // SAFETY: the caller's contract on each pointer, passed on.
    unsafe {
        let result = (|| {
            let (network, navigation, target) = (loaded(policy)?, read_input(navigation)?, read_input(target)?);
            let inputs = lookahead_inputs(spacecraft, settings)?;
            let Network::Transfer(actor) = network else {
                return Err(LT_ERR_WRONG_POLICY_KIND);
            };
            let d = looked_ahead(actor, &navigation.into(), &OrbitShape::from(target), time_to_go, inputs)?;
            Ok((d.command.into(), d.into()))
        })();
        finish_with_report(command, report, result, THRUST_OFF, LOOKAHEAD_REFUSED)
    }
}

/// One rendezvous guidance cycle with rollout lookahead: as `lt_transfer_lookahead_step`, with
/// the target body's state now (the rollouts coast it).
///
/// # Safety
/// As `lt_transfer_lookahead_step`.
#[no_mangle]
#[allow(clippy::too_many_arguments)] // the C signature: one pointer per struct
pub unsafe extern "C" fn lt_rendezvous_lookahead_step(
    policy: *const lt_policy,
    navigation: *const lt_navigation_state,
    body: *const lt_body_state,
    time_to_go: f64,
    spacecraft: *const lt_spacecraft,
    settings: *const lt_lookahead_settings,
    command: *mut lt_thrust_command,
    report: *mut lt_lookahead_report,
) -> lt_status {
    // SAFETY: the caller's contract on each pointer, passed on.
    unsafe {
        let result = (|| {
            let (network, navigation, body) = (loaded(policy)?, read_input(navigation)?, read_input(body)?);
            let inputs = lookahead_inputs(spacecraft, settings)?;
            let Network::Rendezvous(actor) = network else {
                return Err(LT_ERR_WRONG_POLICY_KIND);
            };
            let d = looked_ahead(
                actor,
                &navigation.into(),
                &CartesianState::from(body),
                time_to_go,
                inputs,
            )?;
            Ok((d.command.into(), d.into()))
        })();
        finish_with_report(command, report, result, THRUST_OFF, LOOKAHEAD_REFUSED)
    }
}

/// What terminal targeting does (`lt_terminal_defaults` fills the defaults).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct lt_terminal_settings {
    /// Position residual counted as one unit of miss (AU); default 0.01.
    pub goal_position: f64,
    /// Velocity residual counted as one unit of miss (AU/t*); default 0.01.
    pub goal_velocity: f64,
    /// Length of a guidance cycle (t*); default 14 days, 0.240829... (the scenario family's).
    pub cycle: f64,
    /// Cycles to go from which the remaining commands are solved (1 to 8); default 8.
    pub cycles: u32,
    /// Iterations per cycle, at most (1 to 64): Gauss-Newton steps, then propellant-lowering
    /// steps once the arrival is met; default 3.
    pub iterations: u32,
}

/// What one terminal-targeting cycle decided, for telemetry.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct lt_terminal_report {
    /// The network's own command.
    pub network: lt_thrust_command,
    /// 1 when the solved plan's command is flown, 0 when the network's.
    pub solved: u32,
    /// 1 when the network's continuation was flown out (its miss below is valid), else 0.
    pub predicted_valid: u32,
    /// Predicted miss of the network's continuation, in goal units.
    pub network_miss: f64,
    /// Predicted miss of the plan flown, in goal units (NaN when none was solved).
    pub planned_miss: f64,
}

/// What one three-dimensional terminal-targeting cycle decided, for telemetry: as
/// `lt_terminal_report`, with the network's RTN command.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct lt_terminal_report3 {
    /// The network's own command.
    pub network: lt_rtn_command,
    /// 1 when the solved plan's command is flown, 0 when the network's.
    pub solved: u32,
    /// 1 when the network's continuation was flown out (its miss below is valid), else 0.
    pub predicted_valid: u32,
    /// Predicted miss of the network's continuation, in goal units.
    pub network_miss: f64,
    /// Predicted miss of the plan flown, in goal units (NaN when none was solved).
    pub planned_miss: f64,
}

impl From<lt_terminal_settings> for TerminalSettings {
    fn from(s: lt_terminal_settings) -> Self {
        Self {
            goal_position: s.goal_position,
            goal_velocity: s.goal_velocity,
            cycles: s.cycles,
            iterations: s.iterations,
            cycle: s.cycle,
            ..Self::default()
        }
    }
}

/// Writes the default terminal-targeting settings to `*out`. Returns `LT_OK`, or
/// `LT_ERR_NULL_POINTER`.
///
/// # Safety
/// `out` is null or valid for writing an `lt_terminal_settings` (any alignment).
#[no_mangle]
pub unsafe extern "C" fn lt_terminal_defaults(out: *mut lt_terminal_settings) -> lt_status {
    if out.is_null() {
        return LT_ERR_NULL_POINTER;
    }
    let d = TerminalSettings::default();
    let settings = lt_terminal_settings {
        goal_position: d.goal_position,
        goal_velocity: d.goal_velocity,
        cycles: d.cycles,
        iterations: d.iterations,
        cycle: d.cycle,
    };
    // SAFETY: non-null and writable by the caller's contract; unaligned writes are allowed.
    unsafe { ptr::write_unaligned(out, settings) };
    LT_OK
}

/// Terminal targeting's spacecraft and settings, checked.
///
/// # Safety
/// Each pointer is null or valid for reading its struct.
unsafe fn terminal_inputs(
    spacecraft: *const lt_spacecraft,
    settings: *const lt_terminal_settings,
) -> Result<(CanonicalSpacecraft, TerminalSettings), lt_status> {
    let usable = |s: &TerminalSettings| s.validate().is_ok();
    // SAFETY: the caller's contract on each pointer, passed on.
    unsafe { aid_inputs(spacecraft, settings, usable, LT_ERR_INPUT_TERMINAL) }
}

/// One terminal-targeting cycle of `actor` towards `target`, in either dimension.
fn targeted<const N: usize, const OUT: usize, A: Actor<N, OUT>, T: Aim<N, OUT>>(
    actor: &A,
    navigation: &<T::Geometry as Dimension>::State,
    target: &T,
    time_to_go: f64,
    inputs: (CanonicalSpacecraft, TerminalSettings),
) -> Result<TerminalDecision<<T::Geometry as Dimension>::Command>, lt_status> {
    terminal_step(actor, navigation, target, time_to_go, &inputs.0, &inputs.1).map_err(|e| guidance_error_code(&e))
}

impl From<TerminalDecision<ThrustCommand>> for lt_terminal_report {
    fn from(d: TerminalDecision<ThrustCommand>) -> Self {
        Self {
            network: d.network.into(),
            solved: u32::from(d.solved),
            predicted_valid: u32::from(d.network_miss.is_some()),
            network_miss: d.network_miss.unwrap_or(f64::NAN),
            planned_miss: d.planned_miss.unwrap_or(f64::NAN),
        }
    }
}

impl From<TerminalDecision<RtnCommand>> for lt_terminal_report3 {
    fn from(d: TerminalDecision<RtnCommand>) -> Self {
        Self {
            network: d.network.into(),
            solved: u32::from(d.solved),
            predicted_valid: u32::from(d.network_miss.is_some()),
            network_miss: d.network_miss.unwrap_or(f64::NAN),
            planned_miss: d.planned_miss.unwrap_or(f64::NAN),
        }
    }
}

/// The terminal-targeting report of a refused cycle: the thrust-off command, nothing predicted.
const TERMINAL_REFUSED: lt_terminal_report = lt_terminal_report {
    network: THRUST_OFF,
    solved: 0,
    predicted_valid: 0,
    network_miss: f64::NAN,
    planned_miss: f64::NAN,
};

/// One transfer guidance cycle with terminal targeting (`onboard::terminal::terminal_step`):
/// with `settings.cycles` cycles to go or fewer, the remaining commands are solved for the
/// arrival with the onboard propagator and `spacecraft` (damped Gauss-Newton from the network's
/// continuation) and the plan's first command returned when it predicts a smaller miss than
/// the network's; with more cycles to go, the network's command. At most
/// `2 + iterations x (2 k + 4)` propagations of the k cycles left (with the defaults at most
/// about 89 million Cortex-M4F instructions, at 4 cycles to go): run it at the guidance rate.
///
/// Returns as `lt_transfer_step`, and `LT_ERR_INPUT_TERMINAL` for an unusable spacecraft or
/// settings; `report` may be null, else it receives the decision (nothing predicted on error).
///
/// # Safety
/// As `lt_transfer_step`; `spacecraft` and `settings` are null or valid for reading their
/// structs, `report` null or valid for writing an `lt_terminal_report`.
#[no_mangle]
#[allow(clippy::too_many_arguments)] // the C signature: one pointer per struct
pub unsafe extern "C" fn lt_transfer_terminal_step(
    policy: *const lt_policy,
    navigation: *const lt_navigation_state,
    target: *const lt_target_orbit,
    time_to_go: f64,
    spacecraft: *const lt_spacecraft,
    settings: *const lt_terminal_settings,
    command: *mut lt_thrust_command,
    report: *mut lt_terminal_report,
) -> lt_status {
    // SAFETY: the caller's contract on each pointer, passed on.
    unsafe {
        let result = (|| {
            let (network, navigation, target) = (loaded(policy)?, read_input(navigation)?, read_input(target)?);
            let inputs = terminal_inputs(spacecraft, settings)?;
            let Network::Transfer(actor) = network else {
                return Err(LT_ERR_WRONG_POLICY_KIND);
            };
            let d = targeted(actor, &navigation.into(), &OrbitShape::from(target), time_to_go, inputs)?;
            Ok((d.command.into(), d.into()))
        })();
        finish_with_report(command, report, result, THRUST_OFF, TERMINAL_REFUSED)
    }
}

/// One rendezvous guidance cycle with terminal targeting: as `lt_transfer_terminal_step`, with
/// the target body's state now (the rollouts coast it).
///
/// # Safety
/// As `lt_transfer_terminal_step`.
#[no_mangle]
#[allow(clippy::too_many_arguments)] // the C signature: one pointer per struct
pub unsafe extern "C" fn lt_rendezvous_terminal_step(
    policy: *const lt_policy,
    navigation: *const lt_navigation_state,
    body: *const lt_body_state,
    time_to_go: f64,
    spacecraft: *const lt_spacecraft,
    settings: *const lt_terminal_settings,
    command: *mut lt_thrust_command,
    report: *mut lt_terminal_report,
) -> lt_status {
    // SAFETY: the caller's contract on each pointer, passed on.
    unsafe {
        let result = (|| {
            let (network, navigation, body) = (loaded(policy)?, read_input(navigation)?, read_input(body)?);
            let inputs = terminal_inputs(spacecraft, settings)?;
            let Network::Rendezvous(actor) = network else {
                return Err(LT_ERR_WRONG_POLICY_KIND);
            };
            let d = targeted(
                actor,
                &navigation.into(),
                &CartesianState::from(body),
                time_to_go,
                inputs,
            )?;
            Ok((d.command.into(), d.into()))
        })();
        finish_with_report(command, report, result, THRUST_OFF, TERMINAL_REFUSED)
    }
}

/// The three-dimensional terminal-targeting report of a refused cycle.
const TERMINAL3_REFUSED: lt_terminal_report3 = lt_terminal_report3 {
    network: RTN_THRUST_OFF,
    solved: 0,
    predicted_valid: 0,
    network_miss: f64::NAN,
    planned_miss: f64::NAN,
};

/// One three-dimensional transfer guidance cycle with rollout lookahead: as
/// `lt_transfer_lookahead_step`, with the state, target orbit and command of
/// `lt_transfer3_step` (candidates turned about the local normal, their normal component kept).
///
/// # Safety
/// As `lt_transfer_lookahead_step`, with `command` null or valid for writing an
/// `lt_rtn_command` and `report` null or valid for writing an `lt_lookahead_report3`.
#[no_mangle]
#[allow(clippy::too_many_arguments)] // the C signature: one pointer per struct
pub unsafe extern "C" fn lt_transfer3_lookahead_step(
    policy: *const lt_policy,
    navigation: *const lt_navigation_state3,
    target: *const lt_target_orbit3,
    time_to_go: f64,
    spacecraft: *const lt_spacecraft,
    settings: *const lt_lookahead_settings,
    command: *mut lt_rtn_command,
    report: *mut lt_lookahead_report3,
) -> lt_status {
    // SAFETY: the caller's contract on each pointer, passed on.
    unsafe {
        let result = (|| {
            let (network, navigation, target) = (loaded(policy)?, read_input(navigation)?, read_input(target)?);
            let inputs = lookahead_inputs(spacecraft, settings)?;
            let Network::Transfer3(actor) = network else {
                return Err(LT_ERR_WRONG_POLICY_KIND);
            };
            let d = looked_ahead(
                actor,
                &navigation.into(),
                &TargetOrbit3::from(target),
                time_to_go,
                inputs,
            )?;
            Ok((d.command.into(), d.into()))
        })();
        finish_with_report(command, report, result, RTN_THRUST_OFF, LOOKAHEAD3_REFUSED)
    }
}

/// One three-dimensional rendezvous guidance cycle with rollout lookahead: as
/// `lt_transfer3_lookahead_step`, with the target body's state now (the rollouts coast it).
///
/// # Safety
/// As `lt_transfer3_lookahead_step`.
#[no_mangle]
#[allow(clippy::too_many_arguments)] // the C signature: one pointer per struct
pub unsafe extern "C" fn lt_rendezvous3_lookahead_step(
    policy: *const lt_policy,
    navigation: *const lt_navigation_state3,
    body: *const lt_body_state3,
    time_to_go: f64,
    spacecraft: *const lt_spacecraft,
    settings: *const lt_lookahead_settings,
    command: *mut lt_rtn_command,
    report: *mut lt_lookahead_report3,
) -> lt_status {
    // SAFETY: the caller's contract on each pointer, passed on.
    unsafe {
        let result = (|| {
            let (network, navigation, body) = (loaded(policy)?, read_input(navigation)?, read_input(body)?);
            let inputs = lookahead_inputs(spacecraft, settings)?;
            let Network::Rendezvous3(actor) = network else {
                return Err(LT_ERR_WRONG_POLICY_KIND);
            };
            let d = looked_ahead(actor, &navigation.into(), &SpatialState::from(body), time_to_go, inputs)?;
            Ok((d.command.into(), d.into()))
        })();
        finish_with_report(command, report, result, RTN_THRUST_OFF, LOOKAHEAD3_REFUSED)
    }
}

/// One three-dimensional transfer guidance cycle with terminal targeting: as
/// `lt_transfer_terminal_step`, with the state, target orbit and command of `lt_transfer3_step`
/// (three thrust components a cycle: with the defaults at most 428 propagated cycles).
///
/// # Safety
/// As `lt_transfer_terminal_step`, with `command` null or valid for writing an
/// `lt_rtn_command` and `report` null or valid for writing an `lt_terminal_report3`.
#[no_mangle]
#[allow(clippy::too_many_arguments)] // the C signature: one pointer per struct
pub unsafe extern "C" fn lt_transfer3_terminal_step(
    policy: *const lt_policy,
    navigation: *const lt_navigation_state3,
    target: *const lt_target_orbit3,
    time_to_go: f64,
    spacecraft: *const lt_spacecraft,
    settings: *const lt_terminal_settings,
    command: *mut lt_rtn_command,
    report: *mut lt_terminal_report3,
) -> lt_status {
    // SAFETY: the caller's contract on each pointer, passed on.
    unsafe {
        let result = (|| {
            let (network, navigation, target) = (loaded(policy)?, read_input(navigation)?, read_input(target)?);
            let inputs = terminal_inputs(spacecraft, settings)?;
            let Network::Transfer3(actor) = network else {
                return Err(LT_ERR_WRONG_POLICY_KIND);
            };
            let d = targeted(
                actor,
                &navigation.into(),
                &TargetOrbit3::from(target),
                time_to_go,
                inputs,
            )?;
            Ok((d.command.into(), d.into()))
        })();
        finish_with_report(command, report, result, RTN_THRUST_OFF, TERMINAL3_REFUSED)
    }
}

/// One three-dimensional rendezvous guidance cycle with terminal targeting: as
/// `lt_transfer3_terminal_step`, with the target body's state now (the rollouts coast it).
///
/// # Safety
/// As `lt_transfer3_terminal_step`.
#[no_mangle]
#[allow(clippy::too_many_arguments)] // the C signature: one pointer per struct
pub unsafe extern "C" fn lt_rendezvous3_terminal_step(
    policy: *const lt_policy,
    navigation: *const lt_navigation_state3,
    body: *const lt_body_state3,
    time_to_go: f64,
    spacecraft: *const lt_spacecraft,
    settings: *const lt_terminal_settings,
    command: *mut lt_rtn_command,
    report: *mut lt_terminal_report3,
) -> lt_status {
    // SAFETY: the caller's contract on each pointer, passed on.
    unsafe {
        let result = (|| {
            let (network, navigation, body) = (loaded(policy)?, read_input(navigation)?, read_input(body)?);
            let inputs = terminal_inputs(spacecraft, settings)?;
            let Network::Rendezvous3(actor) = network else {
                return Err(LT_ERR_WRONG_POLICY_KIND);
            };
            let d = targeted(actor, &navigation.into(), &SpatialState::from(body), time_to_go, inputs)?;
            Ok((d.command.into(), d.into()))
        })();
        finish_with_report(command, report, result, RTN_THRUST_OFF, TERMINAL3_REFUSED)
    }
}

/// Writes what a loaded policy flies (problem, quantization) and the mission its blob carries
/// (guidance cycle, units, family) to `*info`: for telemetry, and for the aids' settings.
/// Returns `LT_OK`, `LT_ERR_NOT_LOADED`, `LT_ERR_NULL_POINTER` or `LT_ERR_MISALIGNED_POLICY`.
///
/// # Safety
/// `policy` as in `lt_transfer_step`; `info` is null or valid for writing an `lt_policy_info`.
#[no_mangle]
pub unsafe extern "C" fn lt_policy_describe(policy: *const lt_policy, info: *mut lt_policy_info) -> lt_status {
    if info.is_null() {
        return LT_ERR_NULL_POINTER;
    }
    // SAFETY: the caller's contract on `policy`.
    let network = match unsafe { loaded(policy) } {
        Ok(network) => network,
        Err(code) => return code,
    };
    let quantization = |q| match q {
        Quantization::F32 => LT_QUANTIZATION_F32,
        Quantization::Int8 => LT_QUANTIZATION_INT8,
    };
    let (problem, q, mission) = match network {
        Network::Transfer(p) => (LT_PROBLEM_TRANSFER, p.quantization(), p.mission()),
        Network::Rendezvous(p) => (LT_PROBLEM_RENDEZVOUS, p.quantization(), p.mission()),
        Network::Transfer3(p) => (LT_PROBLEM_TRANSFER3, p.quantization(), p.mission()),
        Network::Rendezvous3(p) => (LT_PROBLEM_RENDEZVOUS3, p.quantization(), p.mission()),
    };
    let described = lt_policy_info {
        problem,
        quantization: quantization(q),
        cycle: mission.cycle,
        length_unit_m: mission.length_unit_m,
        time_unit_s: mission.time_unit_s,
        family: mission.family,
    };
    // SAFETY: non-null and writable by the caller's contract; unaligned writes are allowed.
    unsafe { ptr::write_unaligned(info, described) };
    LT_OK
}

/// Bare metal: a panic cannot happen (see the crate lints), but if one did, it must not return
/// into C. A permanently undefined instruction raises a fault (HardFault on a Cortex-M), which
/// hands control to the flight software's fault response (reset, safe mode).
#[cfg(target_os = "none")]
#[panic_handler]
fn panic(_: &core::panic::PanicInfo<'_>) -> ! {
    loop {
        #[cfg(target_arch = "arm")]
        // SAFETY: `udf` touches no memory or register; it only raises the fault.
        unsafe {
            core::arch::asm!("udf #0", options(nomem, nostack))
        };
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::ffi::CStr;
    use onboard::dynamics::StateError;
    use onboard::features::FeatureError;
    use onboard::policy::{LayerArray, LayerShape, PolicyError};
    use shared::blob::{Activation, ArrayKind, BlobError, PayloadError, ProblemKind};
    use std::collections::HashSet;

    #[test]
    fn the_policy_storage_holds_a_loaded_network_with_room_to_spare() {
        std::println!("Loaded: {} bytes of {}", size_of::<Loaded>(), size_of::<lt_policy>());
        assert_eq!(align_of::<lt_policy>(), 8);
        assert!(size_of::<Loaded>() * 3 / 2 <= size_of::<lt_policy>());
    }

    /// One value of every `BlobError` variant (the match in `blob_error_code` has no wildcard,
    /// so a new variant fails to compile there; this list makes it fail here too when a code is
    /// shared).
    fn every_blob_error() -> std::vec::Vec<BlobError> {
        std::vec![
            BlobError::Truncated { needed: 14, found: 3 },
            BlobError::TrailingBytes {
                expected: 20,
                found: 21
            },
            BlobError::BadMagic { found: *b"XXXX" },
            BlobError::UnsupportedVersion { found: 3, supported: 2 },
            BlobError::CrcMismatch { stored: 1, computed: 2 },
            BlobError::Payload(PayloadError::BadEnum),
            BlobError::PayloadNotConsumed { unused: 1 },
            BlobError::KindMismatch {
                kind: ProblemKind::Rendezvous,
                features: FeatureLayout::TransferPolar10,
            },
            BlobError::NoLayers,
            BlobError::TooManyLayers { found: 5, max: 4 },
            BlobError::InputMismatch {
                expected: 10,
                found: 11
            },
            BlobError::OutputMismatch { expected: 3, found: 4 },
            BlobError::ChainBreak {
                layer: 1,
                expected: 256,
                found: 255,
            },
            BlobError::BadWidth {
                layer: 0,
                inputs: 10,
                outputs: 0,
            },
            BlobError::ArrayLength {
                layer: 0,
                array: ArrayKind::Bias,
                expected: 1024,
                found: 1020,
            },
            BlobError::BadActivation {
                layer: 0,
                expected: Activation::Relu,
                found: Activation::Tanh,
            },
            BlobError::BadScale {
                layer: 0,
                channel: None,
                bits: 0,
            },
            BlobError::NonFiniteWeight {
                layer: 0,
                array: ArrayKind::Weights,
                index: 0,
            },
            BlobError::BufferTooSmall {
                needed: 2,
                available: 1
            },
            BlobError::PayloadTooLarge { len: usize::MAX },
            BlobError::BadPadding {
                layer: 1,
                len: 2,
                weights_offset: 97,
            },
            BlobError::BadMission,
        ]
    }

    fn every_policy_refusal() -> std::vec::Vec<PolicyError> {
        let shape = LayerShape {
            inputs: 10,
            outputs: 256,
        };
        std::vec![
            PolicyError::WrongKind {
                expected: ProblemKind::Transfer,
                found: ProblemKind::Rendezvous,
            },
            PolicyError::WrongFeatures {
                expected_inputs: 10,
                found: FeatureLayout::RendezvousPolar22,
            },
            PolicyError::WrongLayerCount { expected: 3, found: 2 },
            PolicyError::WrongShape {
                layer: 0,
                expected: shape,
                found: shape,
            },
            PolicyError::WrongArrayLength {
                layer: 0,
                array: LayerArray::WeightScales,
                expected: 4,
                found: 0,
            },
            PolicyError::WrongActivation {
                layer: 2,
                expected: Activation::Tanh,
                found: Activation::Relu,
            },
            PolicyError::BadScale { layer: 1 },
            PolicyError::TooWideForInt8 { layer: 0, inputs: 600 },
        ]
    }

    fn every_guidance_error() -> std::vec::Vec<GuidanceError> {
        let input = GuidanceError::Input;
        std::vec![
            input(FeatureError::State(StateError::NonFinite)),
            input(FeatureError::State(StateError::ZeroRadius)),
            input(FeatureError::State(StateError::NonPositiveMass)),
            input(FeatureError::Target),
            input(FeatureError::TimeToGo),
            input(FeatureError::NoOrbitPlane),
            GuidanceError::NonFiniteAction,
        ]
    }

    #[test]
    fn every_refusal_has_its_own_negative_code_with_its_own_name() {
        let mut codes: std::vec::Vec<lt_status> = every_blob_error().iter().map(blob_error_code).collect();
        codes.extend(every_policy_refusal().iter().map(policy_error_code));
        codes.extend(every_guidance_error().iter().map(guidance_error_code));
        codes.extend([
            LT_ERR_NULL_POINTER,
            LT_ERR_MISALIGNED_POLICY,
            LT_ERR_BLOB_LENGTH,
            LT_ERR_NOT_LOADED,
            LT_ERR_WRONG_POLICY_KIND,
            LT_ERR_INPUT_LOOKAHEAD,
            LT_ERR_INPUT_TERMINAL,
        ]);
        let distinct: HashSet<lt_status> = codes.iter().copied().collect();
        assert_eq!(distinct.len(), codes.len(), "a code is shared: {codes:?}");
        assert!(codes.iter().all(|&c| (c as i32) < 0));
        // Blob errors inside a policy refusal keep their code.
        for e in every_blob_error() {
            assert_eq!(policy_error_code(&PolicyError::Blob(e)), blob_error_code(&e));
        }
        // The table lists exactly these codes and LT_OK, each with a distinct name.
        let table: HashSet<lt_status> = all_codes().collect();
        assert_eq!(table, distinct.iter().copied().chain([LT_OK]).collect());
        let names: HashSet<&CStr> = all_codes().map(|c| error_name(c as i32)).collect();
        assert_eq!(names.len(), table.len());
        assert!(!names.contains(UNKNOWN_CODE_NAME));
        assert_eq!(error_name(1), UNKNOWN_CODE_NAME);
        assert_eq!(error_name(-6), UNKNOWN_CODE_NAME);
        assert_eq!(error_name(LT_ERR_BLOB_CRC_MISMATCH as i32), c"blob_crc_mismatch");
    }
}
