//! Where the instructions of one inference go: each stage of the policy's forward pass timed
//! alone (the layer views are public), [`REPEATS`] back-to-back calls per stage.

use core::fmt::{self, Write};
use core::hint::black_box;

use firmware_sim::trace::COMMENT;
use firmware_sim::Policy;
use onboard::policy::MlpLayers;

use crate::counter::{Counter, INSTRUCTIONS_PER_TICK};

const REPEATS: u32 = 64;

/// Instructions per call of `f(input)`, in hundredths.
fn per_call<I, R>(counter: &Counter, input: &I, mut f: impl FnMut(&I) -> R) -> u64 {
    let t0 = counter.now();
    for _ in 0..REPEATS {
        // Opaque input and output: every repetition is computed, none hoisted.
        black_box(f(black_box(input)));
    }
    let t1 = counter.now();
    u64::from(Counter::ticks(t0, t1)) * u64::from(INSTRUCTIONS_PER_TICK) * 100 / u64::from(REPEATS)
}

/// `f(y)` on the array `y`, which stays observable (the writes are not dropped).
fn into<const M: usize>(y: &mut [f32; M], f: impl FnOnce(&mut [f32; M])) {
    f(black_box(&mut *y));
    black_box(y);
}

struct Hundredths(u64);

impl fmt::Display for Hundredths {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", (self.0 + 50) / 100)
    }
}

/// A stage's name, with the network's input count where it has one (10 or 22).
struct Stage(&'static str, Option<usize>, &'static str);

impl fmt::Display for Stage {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.0)?;
        if let Some(n) = self.1 {
            write!(f, " {n}")?;
        }
        f.write_str(self.2)
    }
}

/// Writes the breakdown of `policy.forward(x)` as comment lines.
pub fn write<W: Write, const N: usize, const OUT: usize>(
    w: &mut W,
    counter: &Counter,
    policy: &Policy<'_, N, OUT>,
    x: &[f32; N],
) -> fmt::Result {
    let whole = per_call(counter, x, |x| policy.forward(x));
    // A hidden layer's output, written in place as the network writes it.
    let mut out = [0.0f32; 256];
    // Standalone copies: LLVM inlines and schedules them apart from the flight's Controller::act,
    // so their sum differs from the flight's count by a few per cent.
    write!(
        w,
        "{COMMENT} profile, stages called alone: forward {}",
        Hundredths(whole)
    )?;
    let mut parts = 0;
    match policy.layers() {
        MlpLayers::Int8(a, b, c) => {
            let relu = |mut v: [f32; 256]| {
                v.iter_mut().for_each(|e| *e = e.max(0.0));
                v
            };
            let q1 = b.quantize_input(&relu(a.forward(x)));
            let h2 = relu(b.forward(&q1));
            let l2 = per_call(counter, &q1, |q| b.accumulate(q));
            let stages = [
                (
                    Stage("L1 f32", Some(N), "x256"),
                    per_call(counter, x, |x| into(&mut out, |y| a.forward_into(x, y))),
                ),
                (
                    Stage("L2 quantize 256", None, ""),
                    per_call(counter, &[0.5f32; 256], |h| b.quantize_input(h)),
                ),
                (Stage("L2 accumulate 256x256", None, ""), l2),
                (Stage("L2 dequantize 256", None, ""), {
                    let all = per_call(counter, &q1, |q| b.forward(q));
                    all.saturating_sub(l2)
                }),
                (
                    Stage("L3 f32 256 to", Some(OUT), ""),
                    per_call(counter, &h2, |h| c.forward(h)),
                ),
            ];
            for (name, v) in stages {
                write!(w, "; {name} {}", Hundredths(v))?;
                parts += v;
            }
            let mac = l2 / (256 * 256);
            write!(w, " ({}.{:02} per MAC)", mac / 100, mac % 100)?;
        }
        MlpLayers::F32(a, b, c) => {
            let relu = |mut v: [f32; 256]| {
                v.iter_mut().for_each(|e| *e = e.max(0.0));
                v
            };
            let h1 = relu(a.forward(x));
            let h2 = relu(b.forward(&h1));
            let l2 = per_call(counter, &h1, |h| into(&mut out, |y| b.forward_into(h, y)));
            let stages = [
                (
                    Stage("L1", Some(N), "x256"),
                    per_call(counter, x, |x| into(&mut out, |y| a.forward_into(x, y))),
                ),
                (Stage("L2 256x256", None, ""), l2),
                (
                    Stage("L3 256 to", Some(OUT), ""),
                    per_call(counter, &h2, |h| c.forward(h)),
                ),
            ];
            for (name, v) in stages {
                write!(w, "; {name} {}", Hundredths(v))?;
                parts += v;
            }
            let mac = l2 / (256 * 256);
            write!(w, " ({}.{:02} per MAC)", mac / 100, mac % 100)?;
        }
    }
    writeln!(w, "; the rest {}", Hundredths(whole.saturating_sub(parts)))
}
