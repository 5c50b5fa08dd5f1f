//! The host twin of the Cortex-M4 image: flies the trace's flights (`firmware_sim::trace`)
//! with the blob in the given file and prints the same trace the image prints under QEMU.
//!
//! `sil_trace BLOB [--rendezvous] [--spatial] [--latency]`. The image is built for one problem,
//! and so is its twin: transfer by default (a rendezvous blob is refused), with `--rendezvous`
//! the rendezvous image (a transfer blob is refused); with `--spatial` the problem in three
//! dimensions (the inclined trace flights; a planar blob is refused, and a 3D blob by a planar
//! twin). With `--latency` it also times the inference on the host (lines starting with `#`,
//! which the trace diff ignores).

use std::fmt::Write as _;
use std::hint::black_box;
use std::process::ExitCode;
use std::time::Instant;

use firmware_sim::trace::{self, flights_of, TraceProblem};
use firmware_sim::{Controller, Rendezvous, Rendezvous3, Transfer, Transfer3};
use onboard::features::{ACTION3_LEN, ACTION_LEN};
use onboard::guidance::{Actor, Guide};

/// Host latency: the median over batches of inferences on the nominal flight's features.
fn latency<const N: usize, const OUT: usize>(controller: &Controller<'_, N, OUT>, inputs: &[[f32; N]]) -> String {
    const BATCHES: usize = 31;
    const PER_BATCH: usize = 200;
    let mut ns: Vec<f64> = Vec::with_capacity(BATCHES);
    for b in 0..=BATCHES {
        let start = Instant::now();
        for k in 0..PER_BATCH {
            let x = &inputs[(b * PER_BATCH + k) % inputs.len()];
            black_box(controller.act(black_box(x)));
        }
        let per = start.elapsed().as_secs_f64() * 1e9 / PER_BATCH as f64;
        // The first batch warms caches and branch predictors.
        if b > 0 {
            ns.push(per);
        }
    }
    ns.sort_by(f64::total_cmp);
    format!(
        "{} host latency per inference: median {:.0} ns, min {:.0} ns ({} batches of {PER_BATCH}, 1 thread)",
        trace::COMMENT,
        ns[ns.len() / 2],
        ns[0],
        ns.len()
    )
}

/// The trace of `blob` flown as problem `P`, as the image built for `P` writes it.
fn trace_of<const N: usize, const OUT: usize, P: TraceProblem<N>>(
    problem: P,
    blob: &[u8],
    timing: bool,
) -> Result<String, String>
where
    for<'a> Recorder<'a, N, OUT>: Guide<N, P::Target, P::Geometry>,
{
    let controller = Controller::<N, OUT>::load::<P>(blob);
    let mut out = String::new();
    let mut inputs = Vec::new();
    trace::write_header(&mut out, blob, &controller).map_err(|e| e.to_string())?;
    for (i, flight) in flights_of(problem).iter().enumerate() {
        let recorder = Recorder {
            inner: &controller,
            inputs: std::cell::RefCell::new(Vec::new()),
        };
        // How the flight ended is in the trace's `end` line, compared with the image's.
        let _flown = trace::fly(&mut out, problem, &recorder, flight).map_err(|e| e.to_string())?;
        if i == 0 {
            inputs = recorder.inputs.into_inner();
        }
    }
    // Safe mode has no inference to time.
    if timing && matches!(controller, Controller::Network(_)) && !inputs.is_empty() {
        writeln!(out, "{}", latency(&controller, &inputs)).map_err(|e| e.to_string())?;
    }
    Ok(out)
}

fn run() -> Result<(), String> {
    let usage = "usage: sil_trace BLOB [--rendezvous] [--spatial] [--latency]";
    let mut args = std::env::args().skip(1);
    let path = args.next().ok_or(usage)?;
    let (mut rendezvous, mut spatial, mut timing) = (false, false, false);
    for a in args {
        match a.as_str() {
            "--rendezvous" => rendezvous = true,
            "--spatial" => spatial = true,
            "--latency" => timing = true,
            _ => return Err(format!("unknown argument {a}; {usage}")),
        }
    }
    // On a cache line, as the image links it: the latency is the aligned kernels'.
    let blob = shared::blob::AlignedBlob::new(&std::fs::read(&path).map_err(|e| format!("{path}: {e}"))?);
    let bytes = blob.bytes();
    let out = match (rendezvous, spatial) {
        (false, false) => trace_of::<_, ACTION_LEN, _>(Transfer, bytes, timing)?,
        (true, false) => trace_of::<_, ACTION_LEN, _>(Rendezvous, bytes, timing)?,
        (false, true) => trace_of::<_, ACTION3_LEN, _>(Transfer3, bytes, timing)?,
        (true, true) => trace_of::<_, ACTION3_LEN, _>(Rendezvous3, bytes, timing)?,
    };
    print!("{out}");
    Ok(())
}

/// Passes inferences through and keeps their inputs (for the latency measurement).
struct Recorder<'a, const N: usize, const OUT: usize> {
    inner: &'a Controller<'a, N, OUT>,
    inputs: std::cell::RefCell<Vec<[f32; N]>>,
}

impl<const N: usize, const OUT: usize> Actor<N, OUT> for Recorder<'_, N, OUT> {
    fn act(&self, x: &[f32; N]) -> [f32; OUT] {
        self.inputs.borrow_mut().push(*x);
        self.inner.act(x)
    }
}

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("sil_trace: {e}");
            ExitCode::FAILURE
        }
    }
}
