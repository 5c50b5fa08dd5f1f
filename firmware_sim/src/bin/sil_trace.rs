//! The host twin of the Cortex-M4 image: flies the trace's flights (`firmware_sim::trace`)
//! with the blob in the given file and prints the same trace the image prints under QEMU.
//!
//! `sil_trace BLOB [--latency]`. With `--latency` it also times the inference on the host
//! (lines starting with `#`, which the trace diff ignores).

use std::fmt::Write as _;
use std::hint::black_box;
use std::process::ExitCode;
use std::time::Instant;

use firmware_sim::trace::{self, FLIGHTS};
use firmware_sim::Controller;
use onboard::features::TRANSFER_FEATURES;
use onboard::guidance::Actor;

/// Host latency: the median over batches of inferences on the nominal flight's features.
fn latency(controller: &Controller<'_>, inputs: &[[f32; TRANSFER_FEATURES]]) -> String {
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

fn run() -> Result<(), String> {
    let mut args = std::env::args().skip(1);
    let path = args.next().ok_or("usage: sil_trace BLOB [--latency]")?;
    let timing = match args.next().as_deref() {
        None => false,
        Some("--latency") => true,
        Some(a) => return Err(format!("unknown argument {a}")),
    };
    let blob = std::fs::read(&path).map_err(|e| format!("{path}: {e}"))?;
    let controller = Controller::load_transfer(&blob);
    let mut out = String::new();
    let mut inputs = Vec::new();
    trace::write_header(&mut out, &blob, &controller).map_err(|e| e.to_string())?;
    for (i, flight) in FLIGHTS.iter().enumerate() {
        let recorder = Recorder {
            inner: &controller,
            inputs: std::cell::RefCell::new(Vec::new()),
        };
        // How the flight ended is in the trace's `end` line, compared with the image's.
        let _flown = trace::fly(&mut out, &recorder, flight).map_err(|e| e.to_string())?;
        if i == 0 {
            inputs = recorder.inputs.into_inner();
        }
    }
    // Safe mode has no inference to time.
    if timing && matches!(controller, Controller::Network(_)) && !inputs.is_empty() {
        writeln!(out, "{}", latency(&controller, &inputs)).map_err(|e| e.to_string())?;
    }
    print!("{out}");
    Ok(())
}

/// Passes inferences through and keeps their inputs (for the latency measurement).
struct Recorder<'a> {
    inner: &'a Controller<'a>,
    inputs: std::cell::RefCell<Vec<[f32; TRANSFER_FEATURES]>>,
}

impl Actor<TRANSFER_FEATURES> for Recorder<'_> {
    fn act(&self, x: &[f32; TRANSFER_FEATURES]) -> [f32; 3] {
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
