//! One 10-256-256-3 actor inference in f32 and in int8, and the core's multiply-add limit
//! measured with a register-resident FMA kernel, so inference can be reported as a fraction
//! of the machine's peak (68,864 multiply-adds per inference).
//!
//! `RUSTFLAGS="-C target-cpu=native" CARGO_TARGET_DIR=target/native \
//!  cargo bench -p lowthrust-onboard --bench inference`

#[path = "../tests/policy_support/mod.rs"]
mod policy_support;

use std::hint::black_box;
use std::time::{Duration, Instant};

use criterion::{Criterion, Throughput};
use onboard::policy::{MlpLayers, TransferPolicy};
use policy_support::{calibrate, f32_net, int8_net, quantize_net, random_input, RefNet, Rng};
use shared::blob::{AlignedBlob, ProblemKind};

/// Multiply-adds of one 10-256-256-3 inference.
const MACS: u64 = 10 * 256 + 256 * 256 + 256 * 3;
/// Independent accumulators of the peak kernel: 128 f32 = 8 AVX-512 registers, enough to
/// cover FMA latency x throughput (4 cycles x 2 ports) without spilling.
const ACC: usize = 128;
/// FMA rounds per peak-kernel call.
const ROUNDS: usize = 1000;

/// `ACC * ROUNDS` multiply-adds `acc = acc * m + a` on independent register accumulators:
/// fused (`mul_add`, one FMA instruction) when the build targets FMA hardware, else a
/// multiply and an add (without FMA, `mul_add` is a slow exact software routine).
#[inline(never)]
fn fma_peak(acc: &mut [f32; ACC], m: f32, a: f32) {
    let mut r = *acc;
    for _ in 0..ROUNDS {
        for v in r.iter_mut() {
            *v = if cfg!(target_feature = "fma") {
                v.mul_add(m, a)
            } else {
                *v * m + a
            };
        }
    }
    *acc = r;
}

struct Setup {
    f32_blob: Vec<u8>,
    int8_blob: Vec<u8>,
    /// The same blobs on a 64-byte boundary, as `AlignedBlob` (the host SIL) and the images
    /// place them: every weight array on a cache line.
    f32_aligned: AlignedBlob,
    int8_aligned: AlignedBlob,
    inputs: Vec<[f32; 10]>,
}

/// Byte offset of the hidden layer's weights within a 64-byte line.
fn misalignment(blob: &[u8]) -> usize {
    let p = TransferPolicy::from_bytes(blob, ProblemKind::Transfer).unwrap();
    let w = match p.layers() {
        MlpLayers::F32(_, b, _) => b.weights(),
        MlpLayers::Int8(_, b, _) => b.weights(),
    };
    w.as_ptr() as usize % 64
}

fn setup() -> Setup {
    let mut rng = Rng::new(2024);
    let net = RefNet::random(&[10, 256, 256, 3], 1.0, &mut rng);
    let calib: Vec<Vec<f32>> = (0..200).map(|_| random_input(10, &mut rng)).collect();
    let quant = quantize_net(&net, &calibrate(&net, &calib));
    let inputs = (0..64)
        .map(|_| random_input(10, &mut rng).try_into().unwrap())
        .collect();
    let f32_blob = f32_net(&net, ProblemKind::Transfer).encode();
    let int8_blob = int8_net(&net, &quant, ProblemKind::Transfer).encode();
    Setup {
        f32_aligned: AlignedBlob::new(&f32_blob),
        int8_aligned: AlignedBlob::new(&int8_blob),
        f32_blob,
        int8_blob,
        inputs,
    }
}

/// Median seconds per call of `f` over `samples` batches of `batch` calls.
fn median_secs(samples: usize, batch: usize, mut f: impl FnMut()) -> f64 {
    let mut t: Vec<f64> = (0..samples)
        .map(|_| {
            let start = Instant::now();
            for _ in 0..batch {
                f();
            }
            start.elapsed().as_secs_f64() / batch as f64
        })
        .collect();
    t.sort_by(f64::total_cmp);
    t[t.len() / 2]
}

fn benches(c: &mut Criterion, s: &Setup) {
    let p32 = TransferPolicy::from_bytes(&s.f32_blob, ProblemKind::Transfer).unwrap();
    let p8 = TransferPolicy::from_bytes(&s.int8_blob, ProblemKind::Transfer).unwrap();
    let mut g = c.benchmark_group("inference_10_256_256_3");
    g.throughput(Throughput::Elements(MACS));
    let mut i = 0usize;
    g.bench_function("f32", |b| {
        b.iter(|| {
            i = (i + 1) % s.inputs.len();
            p32.forward(black_box(&s.inputs[i]))
        })
    });
    g.bench_function("int8", |b| {
        b.iter(|| {
            i = (i + 1) % s.inputs.len();
            p8.forward(black_box(&s.inputs[i]))
        })
    });
    let a32 = TransferPolicy::from_bytes(s.f32_aligned.bytes(), ProblemKind::Transfer).unwrap();
    let a8 = TransferPolicy::from_bytes(s.int8_aligned.bytes(), ProblemKind::Transfer).unwrap();
    g.bench_function("f32_aligned", |b| {
        b.iter(|| {
            i = (i + 1) % s.inputs.len();
            a32.forward(black_box(&s.inputs[i]))
        })
    });
    g.bench_function("int8_aligned", |b| {
        b.iter(|| {
            i = (i + 1) % s.inputs.len();
            a8.forward(black_box(&s.inputs[i]))
        })
    });
    g.finish();

    // Where the time goes: each layer's kernel alone.
    let mut g = c.benchmark_group("layers");
    if let (MlpLayers::F32(a, b, l3), MlpLayers::Int8(qa, qb, qc)) = (*p32.layers(), *p8.layers()) {
        let h = [0.5f32; 256];
        let q = qb.quantize_input(&h);
        let x = s.inputs[0];
        g.bench_function("f32_10x256", |bch| bch.iter(|| a.forward(black_box(&x))));
        g.bench_function("f32_256x256", |bch| bch.iter(|| b.forward(black_box(&h))));
        g.bench_function("f32_256x3", |bch| bch.iter(|| l3.forward(black_box(&h))));
        g.bench_function("int8_quantize_256", |bch| bch.iter(|| qb.quantize_input(black_box(&h))));
        g.bench_function("int8_f32_10x256", |bch| bch.iter(|| qa.forward(black_box(&x))));
        g.bench_function("int8_256x256", |bch| bch.iter(|| qb.forward(black_box(&q))));
        g.bench_function("int8_256x256_rows", |bch| {
            bch.iter(|| qb.accumulate_rows(black_box(&q)))
        });
        g.bench_function("int8_f32_256x3", |bch| bch.iter(|| qc.forward(black_box(&h))));
    }
    g.finish();

    let mut g = c.benchmark_group("peak");
    g.throughput(Throughput::Elements((ACC * ROUNDS) as u64));
    let mut acc = [1.0f32; ACC];
    g.bench_function("f32_fma", |b| {
        b.iter(|| fma_peak(black_box(&mut acc), black_box(0.999_999), black_box(1e-7)))
    });
    g.finish();
}

fn summary(s: &Setup) {
    let mut acc = [1.0f32; ACC];
    let tp = median_secs(201, 20, || {
        fma_peak(black_box(&mut acc), black_box(0.999_999), black_box(1e-7))
    });
    black_box(acc);
    let peak = (ACC * ROUNDS) as f64 / tp;
    let at_peak = MACS as f64 / peak;
    println!(
        "summary: peak {:.1} G f32 multiply-adds/s on one core ({}, the vector width LLVM \
         picks); one 10-256-256-3 inference = {MACS} MACs = {:.3} us at that peak",
        peak / 1e9,
        if cfg!(target_feature = "fma") {
            "FMA"
        } else {
            "no FMA in this build: multiply + add"
        },
        at_peak * 1e6
    );
    for (name, blob) in [
        ("f32", &s.f32_blob[..]),
        ("int8", &s.int8_blob[..]),
        ("f32 aligned", s.f32_aligned.bytes()),
        ("int8 aligned", s.int8_aligned.bytes()),
    ] {
        let p = TransferPolicy::from_bytes(blob, ProblemKind::Transfer).unwrap();
        let mut i = 0usize;
        let t = median_secs(201, 2000, || {
            i = (i + 1) % s.inputs.len();
            black_box(p.forward(black_box(&s.inputs[i])));
        });
        println!(
            "summary: {name:>12} (hidden weights at +{:2} B in a 64-B line): {:.3} us per \
             inference = {:.1}% of the multiply-add peak above",
            misalignment(blob),
            t * 1e6,
            100.0 * at_peak / t
        );
    }
}

fn main() {
    let s = setup();
    let mut c = Criterion::default()
        .configure_from_args()
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(3));
    benches(&mut c, &s);
    c.final_summary();
    // `cargo bench` passes `--bench`; under `cargo test --all-targets` criterion only runs each
    // benchmark once, and the timing summary is skipped.
    if std::env::args().any(|a| a == "--bench") {
        summary(&s);
    }
}
