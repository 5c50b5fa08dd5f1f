//! Adaptive embedded Runge-Kutta integration, generic over the state size.
//!
//! The method is Dormand and Prince's explicit Runge-Kutta pair of order 8 with the combined
//! 5th/3rd-order error estimator and the order-7 dense output (DOP853, E. Hairer, S. P. Norsett,
//! G. Wanner, "Solving Ordinary Differential Equations I", 2nd ed., Section II.10, and
//! Hairer's Fortran code `dop853.f`). The coefficients below are those of `dop853.f`, as
//! transcribed in SciPy's `scipy/integrate/_ivp/dop853_coefficients.py`; the convergence-order
//! tests in `tests/propagator_integrator.rs` check them.
//!
//! Everything lives on the stack: the stages are `[[f64; N]; 16]`, so N = 5 (the flight code)
//! costs 640 bytes and N = 130 (the ground's state + costate + sensitivities) about 17 KB.
//! No allocation, no panic, and every loop is bounded: the main loop by
//! [`Tolerances::max_steps`], the root finder and the retries by constants, fixed steps by
//! [`Tolerances::MAX_FIXED_STEPS`].
//!
//! Events: after every trial step the system's [`OdeSystem::events`] are evaluated at the end
//! point. When one changed sign (strictly, relative to the side it was on after the previous
//! step; a zero at the start puts it on no side until it leaves zero), the step's dense output
//! is built (4 more evaluations), the earliest zero is located on it by the Illinois method to
//! a few ulps of t, and the step is redone from its start, shortened to end on that zero: just
//! past it (a few ulps), so that the event function has its new sign at the end point and a
//! kink or jump of the right-hand side there is never straddled. The event's side is then
//! flipped, so the same zero is not detected again by the next step. A right-hand side that
//! jumps at the switch should take its branch from a discrete mode switched by the
//! [`Observer`] (see [`Observer::on_event`]) rather than from the sign of the state, which
//! the last stages of the landing step see either way.

use shared::decimal::Decimal6;

/// An ordinary differential equation dy/dt = f(t, y) with N states and E event functions.
///
/// E is the system's own business: the flight dynamics have none (the default, E = 0), the
/// ground solver's state-costate systems two (the throttle switches rho = -eps and rho = +eps).
pub trait OdeSystem<const N: usize, const E: usize = 0> {
    /// Writes f(t, y) into `dydt`.
    fn derivatives(&self, t: f64, y: &[f64; N], dydt: &mut [f64; N]);

    /// Event functions whose sign changes the integrator steps exactly onto (for example the
    /// throttle switches of a bang-bang control). A step that crosses a zero is shortened so
    /// that it ends on the zero. Default: all values positive constants (never crossed).
    fn events(&self, _t: f64, _y: &[f64; N]) -> [f64; E] {
        [1.0; E]
    }
}

/// Accuracy and effort settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tolerances {
    /// Relative error tolerance per component.
    pub relative: f64,
    /// Absolute error tolerance per component.
    pub absolute: f64,
    /// Most accepted + rejected steps one call may take before giving up with an error.
    pub max_steps: u32,
    /// First trial step (t units); 0 lets the integrator choose.
    pub initial_step: f64,
    /// When positive: exactly this many equal DOP853 steps, without error control (the
    /// tolerances, `max_steps` and `initial_step` are then not read). What the onboard aids'
    /// rollouts use: 12 evaluations a step, and a result that is a smooth function of the
    /// initial state and the system (no step-size decision changes under a small
    /// perturbation), so finite differences through it are clean. Systems with events are
    /// refused ([`IntegrationError::InvalidInput`]): fixed steps cannot land on a switch.
    pub fixed_steps: u32,
}

impl Default for Tolerances {
    fn default() -> Self {
        Self::DEFAULT
    }
}

impl Tolerances {
    /// The flight propagator's settings (`Default`): adaptive, relative 1e-12, absolute 1e-13.
    pub const DEFAULT: Self = Self {
        relative: 1e-12,
        absolute: 1e-13,
        max_steps: 100_000,
        initial_step: 0.0,
        fixed_steps: 0,
    };

    /// Most fixed steps one call may ask for: the work stays bounded.
    pub const MAX_FIXED_STEPS: u32 = 1024;

    /// `steps` equal DOP853 steps without error control (see [`Tolerances::fixed_steps`]).
    pub const fn fixed(steps: u32) -> Self {
        Self {
            fixed_steps: steps,
            ..Self::DEFAULT
        }
    }
}

/// Why an integration did not reach its end time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum IntegrationError {
    /// The step budget ran out at time `t`.
    StepBudgetExhausted {
        /// Where it stopped (t units).
        t: f64,
    },
    /// The step size fell below what f64 can resolve at time `t` (a singularity?).
    StepSizeUnderflow {
        /// Where it stopped (t units).
        t: f64,
    },
    /// The derivatives or the state became NaN or infinite at time `t`.
    NonFinite {
        /// Where it stopped (t units).
        t: f64,
    },
    /// Bad arguments: non-finite times or state, tolerances that are not finite and positive,
    /// `max_steps` = 0, a negative or non-finite `initial_step`, or fixed steps above
    /// [`Tolerances::MAX_FIXED_STEPS`] or for a system with events.
    InvalidInput,
}

impl core::fmt::Display for IntegrationError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::StepBudgetExhausted { t } => write!(f, "step budget exhausted at t = {}", Decimal6(*t)),
            Self::StepSizeUnderflow { t } => write!(f, "step size underflow at t = {}", Decimal6(*t)),
            Self::NonFinite { t } => write!(f, "derivatives or state not finite at t = {}", Decimal6(*t)),
            Self::InvalidInput => f.write_str(
                "invalid input: times and state must be finite, tolerances finite and > 0, max_steps > 0, \
                 initial_step finite and >= 0, fixed steps at most 1024 and only for systems without events",
            ),
        }
    }
}

impl core::error::Error for IntegrationError {}

/// What an integration did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct IntegrationStats {
    /// Steps kept (including the steps shortened to end on an event).
    pub accepted_steps: u32,
    /// Trial steps not kept: error too large, non-finite values, or cut short at an event
    /// (the shortened redo is then counted as accepted or rejected on its own).
    pub rejected_steps: u32,
    /// Evaluations of the right-hand side f(t, y).
    pub derivative_evaluations: u32,
    /// Steps that were shortened to end on an event (switch).
    pub events_located: u32,
}

/// Receives the accepted steps and the located events of [`integrate_observed`].
pub trait Observer<const N: usize> {
    /// Called after every accepted step with its end time and state.
    fn on_step(&mut self, _t: f64, _y: &[f64; N]) {}

    /// Called after an accepted step that ended on a zero of event function `index`
    /// (after [`Observer::on_step`] for the same step). `rising` is true for a - to + crossing.
    /// The step ends a few ulps past the zero, so the event function has its new sign there.
    /// The integrator evaluates the derivative at this point again after this call, so a system
    /// with a discrete mode (for example a `Cell` that this observer switches) continues with
    /// the new mode; the steps never see a mode change inside them.
    fn on_event(&mut self, _index: usize, _t: f64, _y: &[f64; N], _rising: bool) {}
}

/// The observer that ignores everything.
impl<const N: usize> Observer<N> for () {}

/// Integrates `system` from (t0, y0) to t1 (t1 may be before t0), returning y(t1).
pub fn integrate<S: OdeSystem<N, E>, const N: usize, const E: usize>(
    system: &S,
    t0: f64,
    y0: &[f64; N],
    t1: f64,
    tolerances: &Tolerances,
) -> Result<([f64; N], IntegrationStats), IntegrationError> {
    integrate_observed(system, t0, y0, t1, tolerances, &mut ())
}

// ---------------------------------------------------------------------------------------------
// DOP853 coefficients (Hairer's dop853.f; SciPy dop853_coefficients.py). Stages 0..11 form the
// step, stage 12 is f(t + h, y1) (first-same-as-last), stages 13..15 serve the dense output.
// Row s of A holds a(s, 0..s).
// ---------------------------------------------------------------------------------------------

const STAGES: usize = 12;
const ALL_STAGES: usize = 16;

#[allow(clippy::excessive_precision)] // digits as published
const C: [f64; ALL_STAGES] = [
    0.0,
    0.526001519587677318785587544488e-01,
    0.789002279381515978178381316732e-01,
    0.118350341907227396726757197510,
    0.281649658092772603273242802490,
    0.333333333333333333333333333333,
    0.25,
    0.307692307692307692307692307692,
    0.651282051282051282051282051282,
    0.6,
    0.857142857142857142857142857142,
    1.0,
    1.0,
    0.1,
    0.2,
    0.777777777777777777777777777778,
];

#[allow(clippy::excessive_precision)] // digits as published
const A: [[f64; ALL_STAGES - 1]; ALL_STAGES] = {
    let mut a = [[0.0; ALL_STAGES - 1]; ALL_STAGES];
    a[1][0] = 5.26001519587677318785587544488e-2;

    a[2][0] = 1.97250569845378994544595329183e-2;
    a[2][1] = 5.91751709536136983633785987549e-2;

    a[3][0] = 2.95875854768068491816892993775e-2;
    a[3][2] = 8.87627564304205475450678981324e-2;

    a[4][0] = 2.41365134159266685502369798665e-1;
    a[4][2] = -8.84549479328286085344864962717e-1;
    a[4][3] = 9.24834003261792003115737966543e-1;

    a[5][0] = 3.7037037037037037037037037037e-2;
    a[5][3] = 1.70828608729473871279604482173e-1;
    a[5][4] = 1.25467687566822425016691814123e-1;

    a[6][0] = 3.7109375e-2;
    a[6][3] = 1.70252211019544039314978060272e-1;
    a[6][4] = 6.02165389804559606850219397283e-2;
    a[6][5] = -1.7578125e-2;

    a[7][0] = 3.70920001185047927108779319836e-2;
    a[7][3] = 1.70383925712239993810214054705e-1;
    a[7][4] = 1.07262030446373284651809199168e-1;
    a[7][5] = -1.53194377486244017527936158236e-2;
    a[7][6] = 8.27378916381402288758473766002e-3;

    a[8][0] = 6.24110958716075717114429577812e-1;
    a[8][3] = -3.36089262944694129406857109825;
    a[8][4] = -8.68219346841726006818189891453e-1;
    a[8][5] = 2.75920996994467083049415600797e1;
    a[8][6] = 2.01540675504778934086186788979e1;
    a[8][7] = -4.34898841810699588477366255144e1;

    a[9][0] = 4.77662536438264365890433908527e-1;
    a[9][3] = -2.48811461997166764192642586468;
    a[9][4] = -5.90290826836842996371446475743e-1;
    a[9][5] = 2.12300514481811942347288949897e1;
    a[9][6] = 1.52792336328824235832596922938e1;
    a[9][7] = -3.32882109689848629194453265587e1;
    a[9][8] = -2.03312017085086261358222928593e-2;

    a[10][0] = -9.3714243008598732571704021658e-1;
    a[10][3] = 5.18637242884406370830023853209;
    a[10][4] = 1.09143734899672957818500254654;
    a[10][5] = -8.14978701074692612513997267357;
    a[10][6] = -1.85200656599969598641566180701e1;
    a[10][7] = 2.27394870993505042818970056734e1;
    a[10][8] = 2.49360555267965238987089396762;
    a[10][9] = -3.0467644718982195003823669022;

    a[11][0] = 2.27331014751653820792359768449;
    a[11][3] = -1.05344954667372501984066689879e1;
    a[11][4] = -2.00087205822486249909675718444;
    a[11][5] = -1.79589318631187989172765950534e1;
    a[11][6] = 2.79488845294199600508499808837e1;
    a[11][7] = -2.85899827713502369474065508674;
    a[11][8] = -8.87285693353062954433549289258;
    a[11][9] = 1.23605671757943030647266201528e1;
    a[11][10] = 6.43392746015763530355970484046e-1;

    // Row 12 (the solution) is `B`: stage 12 is f(t + h, y1).

    a[13][0] = 5.61675022830479523392909219681e-2;
    a[13][6] = 2.53500210216624811088794765333e-1;
    a[13][7] = -2.46239037470802489917441475441e-1;
    a[13][8] = -1.24191423263816360469010140626e-1;
    a[13][9] = 1.5329179827876569731206322685e-1;
    a[13][10] = 8.20105229563468988491666602057e-3;
    a[13][11] = 7.56789766054569976138603589584e-3;
    a[13][12] = -8.298e-3;

    a[14][0] = 3.18346481635021405060768473261e-2;
    a[14][5] = 2.83009096723667755288322961402e-2;
    a[14][6] = 5.35419883074385676223797384372e-2;
    a[14][7] = -5.49237485713909884646569340306e-2;
    a[14][10] = -1.08347328697249322858509316994e-4;
    a[14][11] = 3.82571090835658412954920192323e-4;
    a[14][12] = -3.40465008687404560802977114492e-4;
    a[14][13] = 1.41312443674632500278074618366e-1;

    a[15][0] = -4.28896301583791923408573538692e-1;
    a[15][5] = -4.69762141536116384314449447206;
    a[15][6] = 7.68342119606259904184240953878;
    a[15][7] = 4.06898981839711007970213554331;
    a[15][8] = 3.56727187455281109270669543021e-1;
    a[15][12] = -1.39902416515901462129418009734e-3;
    a[15][13] = 2.9475147891527723389556272149;
    a[15][14] = -9.15095847217987001081870187138;
    a
};

/// 8th-order weights b (dop853.f B1 .. B12; row 12 of SciPy's A).
#[allow(clippy::excessive_precision)] // digits as published
const B: [f64; STAGES] = [
    5.42937341165687622380535766363e-2,
    0.0,
    0.0,
    0.0,
    0.0,
    4.45031289275240888144113950566,
    1.89151789931450038304281599044,
    -5.8012039600105847814672114227,
    3.1116436695781989440891606237e-1,
    -1.52160949662516078556178806805e-1,
    2.01365400804030348374776537501e-1,
    4.47106157277725905176885569043e-2,
];

/// b minus the 3rd-order weights (bhh1, bhh2, bhh3 of dop853.f at stages 0, 8, 11).
#[allow(clippy::excessive_precision)] // digits as published
const E3: [f64; STAGES] = {
    let mut e = B;
    e[0] -= 0.244094488188976377952755905512;
    e[8] -= 0.733846688281611857341361741547;
    e[11] -= 0.220588235294117647058823529412e-1;
    e
};

/// 5th-order error weights (er1 .. er12 of dop853.f).
#[allow(clippy::excessive_precision)] // digits as published
const E5: [f64; STAGES] = [
    0.1312004499419488073250102996e-1,
    0.0,
    0.0,
    0.0,
    0.0,
    -0.1225156446376204440720569753e1,
    -0.4957589496572501915214079952,
    0.1664377182454986536961530415e1,
    -0.3503288487499736816886487290,
    0.3341791187130174790297318841,
    0.8192320648511571246570742613e-1,
    -0.2235530786388629525884427845e-1,
];

/// Dense-output weights for the 4th to 7th interpolation coefficients (d4j .. d7j of dop853.f).
#[allow(clippy::excessive_precision)] // digits as published
const D: [[f64; ALL_STAGES]; 4] = [
    [
        -0.84289382761090128651353491142e1,
        0.0,
        0.0,
        0.0,
        0.0,
        0.56671495351937776962531783590,
        -0.30689499459498916912797304727e1,
        0.23846676565120698287728149680e1,
        0.21170345824450282767155149946e1,
        -0.87139158377797299206789907490,
        0.22404374302607882758541771650e1,
        0.63157877876946881815570249290,
        -0.88990336451333310820698117400e-1,
        0.18148505520854727256656404962e2,
        -0.91946323924783554000451984436e1,
        -0.44360363875948939664310572000e1,
    ],
    [
        0.10427508642579134603413151009e2,
        0.0,
        0.0,
        0.0,
        0.0,
        0.24228349177525818288430175319e3,
        0.16520045171727028198505394887e3,
        -0.37454675472269020279518312152e3,
        -0.22113666853125306036270938578e2,
        0.77334326684722638389603898808e1,
        -0.30674084731089398182061213626e2,
        -0.93321305264302278729567221706e1,
        0.15697238121770843886131091075e2,
        -0.31139403219565177677282850411e2,
        -0.93529243588444783865713862664e1,
        0.35816841486394083752465898540e2,
    ],
    [
        0.19985053242002433820987653617e2,
        0.0,
        0.0,
        0.0,
        0.0,
        -0.38703730874935176555105901742e3,
        -0.18917813819516756882830838328e3,
        0.52780815920542364900561016686e3,
        -0.11573902539959630126141871134e2,
        0.68812326946963000169666922661e1,
        -0.10006050966910838403183860980e1,
        0.77771377980534432092869265740,
        -0.27782057523535084065932004339e1,
        -0.60196695231264120758267380846e2,
        0.84320405506677161018159903784e2,
        0.11992291136182789328035130030e2,
    ],
    [
        -0.25693933462703749003312586129e2,
        0.0,
        0.0,
        0.0,
        0.0,
        -0.15418974869023643374053993627e3,
        -0.23152937917604549567536039109e3,
        0.35763911791061412378285349910e3,
        0.93405324183624310003907691704e2,
        -0.37458323136451633156875139351e2,
        0.10409964950896230045147246184e3,
        0.29840293426660503123344363579e2,
        -0.43533456590011143754432175058e2,
        0.96324553959188282948394950600e2,
        -0.39177261675615439165231486172e2,
        -0.14972683625798562581422125276e3,
    ],
];

// Step-size controller of dop853.f (defaults): safety factor, bounds on the step ratio.
const SAFETY: f64 = 0.9;
/// Smallest ratio new step / old step after an accepted step (dop853.f FAC1).
const MIN_FACTOR: f64 = 0.333;
/// Largest ratio new step / old step (dop853.f FAC2).
const MAX_FACTOR: f64 = 6.0;
/// Error exponent 1/(q+1) with q = 7 (dop853.f EXPO1 with BETA = 0).
const ERROR_EXPONENT: f64 = 1.0 / 8.0;
/// Unit roundoff used for the step-size underflow test (dop853.f UROUND).
const UROUND: f64 = 2.3e-16;
/// Consecutive trial steps with NaN/inf values tolerated (each shrinks h tenfold).
const MAX_NON_FINITE_TRIALS: u32 = 8;
/// How many times one step may be re-aimed at a more precise event location.
const MAX_EVENT_REFINEMENTS: u32 = 8;
/// Iteration bound of the event root finder (Illinois, then bisection).
const ROOT_ITERATIONS: u32 = 200;
const ROOT_ILLINOIS_ITERATIONS: u32 = 60;

/// y + h * sum_j coeffs[j] k[j], accumulating the increment before adding it to y.
fn combine<const N: usize>(y: &[f64; N], h: f64, coeffs: &[f64], k: &[[f64; N]], out: &mut [f64; N]) {
    let mut acc = [0.0; N];
    for (&a, kj) in coeffs.iter().zip(k) {
        if a != 0.0 {
            for (s, &v) in acc.iter_mut().zip(kj) {
                *s += a * v;
            }
        }
    }
    for ((o, &yi), &s) in out.iter_mut().zip(y).zip(&acc) {
        *o = yi + h * s;
    }
}

/// sum_j coeffs[j] k[j].
fn weighted<const N: usize>(coeffs: &[f64], k: &[[f64; N]]) -> [f64; N] {
    let mut acc = [0.0; N];
    for (&a, kj) in coeffs.iter().zip(k) {
        if a != 0.0 {
            for (s, &v) in acc.iter_mut().zip(kj) {
                *s += a * v;
            }
        }
    }
    acc
}

fn all_finite<const N: usize>(y: &[f64; N]) -> bool {
    y.iter().all(|v| v.is_finite())
}

fn bump(counter: &mut u32, by: u32) {
    *counter = counter.saturating_add(by);
}

/// Evaluates stage `s` (1..16) from the stages before it.
fn stage<S: OdeSystem<N, E>, const N: usize, const E: usize>(
    system: &S,
    t: f64,
    y: &[f64; N],
    h: f64,
    k: &mut [[f64; N]; ALL_STAGES],
    s: usize,
) {
    let (row, c) = match (A.get(s), C.get(s)) {
        (Some(row), Some(&c)) => (row, c),
        _ => return,
    };
    let (done, rest) = k.split_at_mut(s.min(ALL_STAGES));
    let Some(out) = rest.first_mut() else {
        return;
    };
    let mut ys = [0.0; N];
    combine(y, h, row, done, &mut ys);
    system.derivatives(t + c * h, &ys, out);
}

/// The 8th-order solution of one DOP853 step from (t, y) with k[0] = f(t, y): fills k[1..12].
fn advance<S: OdeSystem<N, E>, const N: usize, const E: usize>(
    system: &S,
    t: f64,
    y: &[f64; N],
    h: f64,
    k: &mut [[f64; N]; ALL_STAGES],
) -> [f64; N] {
    for s in 1..STAGES {
        stage(system, t, y, h, k, s);
    }
    let mut y1 = [0.0; N];
    combine(y, h, &B, k, &mut y1);
    y1
}

/// One DOP853 trial step from (t, y) with k[0] = f(t, y): fills k[1..12] and returns the new
/// state and the scaled error norm (<= 1 means acceptable; NaN when something was not finite).
fn trial_step<S: OdeSystem<N, E>, const N: usize, const E: usize>(
    system: &S,
    t: f64,
    y: &[f64; N],
    h: f64,
    k: &mut [[f64; N]; ALL_STAGES],
    tol: &Tolerances,
) -> ([f64; N], f64) {
    let y1 = advance(system, t, y, h, k);
    let e5 = weighted(&E5, k);
    let e3 = weighted(&E3, k);
    let (mut err5, mut err3) = (0.0, 0.0);
    for (((&y0i, &y1i), &e5i), &e3i) in y.iter().zip(&y1).zip(&e5).zip(&e3) {
        let sk = tol.absolute + tol.relative * y0i.abs().max(y1i.abs());
        let a = e5i / sk;
        let b = e3i / sk;
        err5 += a * a;
        err3 += b * b;
    }
    let mut deno = err5 + 0.01 * err3;
    if deno <= 0.0 {
        deno = 1.0;
    }
    #[allow(clippy::cast_precision_loss)]
    let n = N.max(1) as f64;
    let mut err = h.abs() * err5 * libm::sqrt(1.0 / (n * deno));
    let finite = all_finite(&y1) && err5.is_finite() && err3.is_finite();
    if !finite {
        err = f64::NAN;
    }
    (y1, err)
}

/// The order-7 interpolant of one step (dop853.f CONTD8).
struct Dense<const N: usize> {
    t_old: f64,
    h: f64,
    y_old: [f64; N],
    f: [[f64; N]; 7],
}

impl<const N: usize> Dense<N> {
    /// Builds the interpolant of the step (t, y) -> (t + h, y1); k[0..12] hold the step's
    /// stages and k[12] = f(t + h, y1). Evaluates the three extra stages.
    fn new<S: OdeSystem<N, E>, const E: usize>(
        system: &S,
        t: f64,
        y: &[f64; N],
        h: f64,
        y1: &[f64; N],
        k: &mut [[f64; N]; ALL_STAGES],
    ) -> Self {
        for s in (STAGES + 1)..ALL_STAGES {
            stage(system, t, y, h, k, s);
        }
        let mut f = [[0.0; N]; 7];
        let [k0, .., k12, _, _, _] = &*k;
        let [f0, f1, f2, rest @ ..] = &mut f;
        for ((((((a, b), c), &yo), &yn), &s0), &s12) in f0
            .iter_mut()
            .zip(f1.iter_mut())
            .zip(f2.iter_mut())
            .zip(y)
            .zip(y1)
            .zip(k0)
            .zip(k12)
        {
            let dy = yn - yo;
            *a = dy;
            *b = h * s0 - dy;
            *c = 2.0 * dy - h * (s12 + s0);
        }
        for (row, d) in rest.iter_mut().zip(&D) {
            let w = weighted(d, k.as_slice());
            for (o, &v) in row.iter_mut().zip(&w) {
                *o = h * v;
            }
        }
        Self {
            t_old: t,
            h,
            y_old: *y,
            f,
        }
    }

    fn eval(&self, t: f64) -> [f64; N] {
        let x = (t - self.t_old) / self.h;
        let x1 = 1.0 - x;
        let [f0, f1, f2, f3, f4, f5, f6] = &self.f;
        // y_old + x (f0 + x1 (f1 + x (f2 + x1 (f3 + x (f4 + x1 (f5 + x f6)))))), nested.
        let mut acc = *f6;
        for (row, m) in [(f5, x), (f4, x1), (f3, x), (f2, x1), (f1, x), (f0, x1)] {
            for (a, &r) in acc.iter_mut().zip(row) {
                *a = r + m * *a;
            }
        }
        for (a, &yo) in acc.iter_mut().zip(&self.y_old) {
            *a = yo + x * *a;
        }
        acc
    }
}

/// Sign as -1, 0, +1 (NaN counts as 0: an undefined event function never triggers).
fn sign(v: f64) -> i8 {
    if v > 0.0 {
        1
    } else if v < 0.0 {
        -1
    } else {
        0
    }
}

/// Locates a zero of g between `ta` (where g has sign `side` != 0) and `tb` (where it has
/// the opposite sign or is zero). Returns the bracket end on the far side of the zero, within
/// a few ulps of it: g there has sign -side (or is zero when it is `tb` itself).
fn locate_zero(mut ta: f64, mut ga: f64, mut tb: f64, mut gb: f64, mut g: impl FnMut(f64) -> f64) -> f64 {
    let side = sign(ga);
    let mut retained = 0i8;
    for it in 0..ROOT_ITERATIONS {
        if gb == 0.0 {
            return tb;
        }
        let width = (tb - ta).abs();
        if width <= 4.0 * f64::EPSILON * ta.abs().max(tb.abs()) {
            break;
        }
        let mid = ta + 0.5 * (tb - ta);
        let mut tc = tb - gb * (tb - ta) / (gb - ga);
        let inside = if ta < tb {
            ta < tc && tc < tb
        } else {
            tb < tc && tc < ta
        };
        if it >= ROOT_ILLINOIS_ITERATIONS || !inside {
            tc = mid;
        }
        if tc == ta || tc == tb {
            break;
        }
        let gc = g(tc);
        if !gc.is_finite() {
            break;
        }
        // An exact zero counts as the near side: the result stays strictly on the far side.
        let sc = sign(gc);
        if sc == side || sc == 0 {
            ta = tc;
            ga = gc;
            if retained == 1 {
                gb *= 0.5;
            }
            retained = 1;
        } else {
            tb = tc;
            gb = gc;
            if retained == -1 {
                ga *= 0.5;
            }
            retained = -1;
        }
    }
    tb
}

/// Hairer's starting step (dop853.f HINIT) for an order-8 method.
#[allow(clippy::too_many_arguments)]
fn initial_step<S: OdeSystem<N, E>, const N: usize, const E: usize>(
    system: &S,
    t: f64,
    y: &[f64; N],
    f0: &[f64; N],
    direction: f64,
    hmax: f64,
    tol: &Tolerances,
    evaluations: &mut u32,
) -> f64 {
    let (mut dnf, mut dny) = (0.0, 0.0);
    for (&yi, &fi) in y.iter().zip(f0) {
        let sk = tol.absolute + tol.relative * yi.abs();
        dnf += (fi / sk) * (fi / sk);
        dny += (yi / sk) * (yi / sk);
    }
    let mut h = if dnf <= 1e-10 || dny <= 1e-10 {
        1e-6
    } else {
        libm::sqrt(dny / dnf) * 0.01
    };
    h = h.min(hmax);
    let h0 = h;
    let mut y1 = [0.0; N];
    for ((o, &yi), &fi) in y1.iter_mut().zip(y).zip(f0) {
        *o = yi + direction * h * fi;
    }
    let mut f1 = [0.0; N];
    system.derivatives(t + direction * h, &y1, &mut f1);
    bump(evaluations, 1);
    let mut der2 = 0.0;
    for ((&yi, &a), &b) in y.iter().zip(f0).zip(&f1) {
        let sk = tol.absolute + tol.relative * yi.abs();
        der2 += ((b - a) / sk) * ((b - a) / sk);
    }
    let der2 = libm::sqrt(der2) / h;
    let der12 = der2.max(libm::sqrt(dnf));
    let h1 = if der12 <= 1e-15 {
        1e-6_f64.max(h * 1e-3)
    } else {
        libm::pow(0.01 / der12, 1.0 / 8.0)
    };
    let h = (100.0 * h).min(h1).min(hmax);
    if h.is_finite() && h > 0.0 {
        h
    } else {
        h0
    }
}

/// [`integrate`] that reports every accepted step and every located event to `observer`.
///
/// Errors: [`IntegrationError::InvalidInput`] for non-finite t0, t1 or y0, tolerances that are
/// not finite and > 0, `max_steps` = 0 or a negative `initial_step`; then, while integrating,
/// `NonFinite` (the derivative at an accepted point is not finite, or trial steps keep producing
/// NaN/inf), `StepSizeUnderflow` (|h| below ~1e-15 |t|) or `StepBudgetExhausted`.
pub fn integrate_observed<S: OdeSystem<N, E>, O: Observer<N>, const N: usize, const E: usize>(
    system: &S,
    t0: f64,
    y0: &[f64; N],
    t1: f64,
    tolerances: &Tolerances,
    observer: &mut O,
) -> Result<([f64; N], IntegrationStats), IntegrationError> {
    let tol = tolerances;
    let positive = |v: f64| v.is_finite() && v > 0.0;
    let valid = t0.is_finite()
        && t1.is_finite()
        && (t1 - t0).is_finite()
        && all_finite(y0)
        && positive(tol.relative)
        && positive(tol.absolute)
        && tol.max_steps > 0
        && tol.initial_step.is_finite()
        && tol.initial_step >= 0.0
        && tol.fixed_steps <= Tolerances::MAX_FIXED_STEPS
        && (tol.fixed_steps == 0 || E == 0);
    if !valid {
        return Err(IntegrationError::InvalidInput);
    }
    let mut stats = IntegrationStats::default();
    if t1 == t0 {
        return Ok((*y0, stats));
    }
    if tol.fixed_steps > 0 {
        return integrate_fixed(system, t0, y0, t1, tol.fixed_steps, observer);
    }
    let direction = if t1 > t0 { 1.0 } else { -1.0 };
    let hmax = (t1 - t0).abs();

    let mut k = [[0.0; N]; ALL_STAGES];
    let mut t = t0;
    let mut y = *y0;
    {
        let [k0, ..] = &mut k;
        system.derivatives(t, &y, k0);
        bump(&mut stats.derivative_evaluations, 1);
        if !all_finite(k0) {
            return Err(IntegrationError::NonFinite { t });
        }
    }
    // Side of each event function: -1, +1, or 0 (on the zero, no side yet).
    let mut sides = system.events(t, &y).map(sign);

    let mut h = if tol.initial_step > 0.0 {
        tol.initial_step.min(hmax)
    } else {
        let [k0, ..] = &k;
        initial_step(
            system,
            t,
            &y,
            k0,
            direction,
            hmax,
            tol,
            &mut stats.derivative_evaluations,
        )
    } * direction;

    let mut previous_rejected = false;
    let mut non_finite_trials = 0u32;
    // While re-aiming a step at an event: (target time, refinements so far, step proposal of
    // the untruncated trial).
    let mut aiming: Option<(f64, u32, f64)> = None;
    let mut trials = 0u32;

    loop {
        if trials >= tol.max_steps {
            return Err(IntegrationError::StepBudgetExhausted { t });
        }
        trials += 1;

        let mut last = false;
        let t_new;
        if let Some((target, _, _)) = aiming {
            t_new = target;
        } else {
            if !(h.is_finite() && 0.1 * h.abs() > t.abs() * UROUND && h.abs() > f64::MIN_POSITIVE) {
                return Err(IntegrationError::StepSizeUnderflow { t });
            }
            if (t + 1.01 * h - t1) * direction > 0.0 {
                h = t1 - t;
                last = true;
            }
            t_new = if last { t1 } else { t + h };
        }

        let (y_new, err) = trial_step(system, t, &y, h, &mut k, tol);
        bump(&mut stats.derivative_evaluations, (STAGES - 1) as u32);
        if !err.is_finite() {
            bump(&mut stats.rejected_steps, 1);
            non_finite_trials += 1;
            if non_finite_trials > MAX_NON_FINITE_TRIALS {
                return Err(IntegrationError::NonFinite { t });
            }
            h *= 0.1;
            previous_rejected = true;
            aiming = None;
            continue;
        }
        non_finite_trials = 0;

        // Step-size proposal from this trial's error (dop853.f, BETA = 0).
        let fac11 = libm::pow(err, ERROR_EXPONENT);
        let fac = (fac11 / SAFETY).clamp(1.0 / MAX_FACTOR, 1.0 / MIN_FACTOR);
        let h_proposal = h / fac;

        // Events at the end of the trial.
        let g_new = system.events(t_new, &y_new);
        let mut fsal_done = false;
        let mut landed: Option<usize> = None;
        let crossing = sides
            .iter()
            .zip(&g_new)
            .any(|(&s, &g)| s != 0 && sign(g) != s && !g.is_nan());
        if crossing {
            // First-same-as-last stage, then the dense output of this trial.
            {
                let [.., k12, _, _, _] = &mut k;
                system.derivatives(t_new, &y_new, k12);
            }
            fsal_done = true;
            let dense = Dense::new(system, t, &y, t_new - t, &y_new, &mut k);
            bump(&mut stats.derivative_evaluations, 4);
            let g_old = system.events(t, &y);
            // Earliest zero over the events that changed sign.
            let mut earliest: Option<(usize, f64)> = None;
            for (i, ((&s, &gn), &go)) in sides.iter().zip(&g_new).zip(&g_old).enumerate() {
                if s == 0 || sign(gn) == s || gn.is_nan() {
                    continue;
                }
                let event = |tt: f64| system.events(tt, &dense.eval(tt)).get(i).copied().unwrap_or(f64::NAN);
                // Left end of the bracket: the step start, unless the event sits (numerically)
                // on its zero there; then the first interior sample still on side s. None
                // found: the zero is at the start itself.
                let mut left = if sign(go) == s { Some((t, go)) } else { None };
                if left.is_none() {
                    for frac in [1e-9, 1e-6, 1e-3, 0.0625, 0.125, 0.25, 0.375, 0.5, 0.625, 0.75, 0.875] {
                        let tt = t + frac * (t_new - t);
                        let gt = event(tt);
                        if sign(gt) == s {
                            left = Some((tt, gt));
                            break;
                        }
                    }
                }
                let root = match left {
                    _ if gn == 0.0 => t_new,
                    Some((ta, ga)) => locate_zero(ta, ga, t_new, gn, event),
                    None => t,
                };
                let earlier = match earliest {
                    None => true,
                    Some((_, te)) => (root - te) * direction < 0.0,
                };
                if earlier {
                    earliest = Some((i, root));
                }
            }
            if let Some((i, root)) = earliest {
                let scale = t_new.abs().max(t.abs());
                let at_end = (t_new - root).abs() <= 4.0 * f64::EPSILON * scale;
                // Strictly on the new side: the derivative evaluated at the landing point then
                // belongs to the arc after the switch.
                let strict = g_new
                    .get(i)
                    .is_some_and(|&g| sign(g) == -sides.get(i).copied().unwrap_or(0));
                let refinements = aiming.map_or(0, |(_, r, _)| r);
                let nudge = f64::from(4u32 << refinements.min(20)) * f64::EPSILON * scale.max(f64::MIN_POSITIVE);
                let target = if !at_end {
                    // Never aim at (or before) the start: a zero there is passed by a few ulps.
                    let min_past = t + direction * nudge;
                    if (root - min_past) * direction < 0.0 {
                        Some(if (min_past - t_new) * direction < 0.0 {
                            min_past
                        } else {
                            t_new
                        })
                    } else {
                        Some(root)
                    }
                } else if !strict {
                    // The step ends on the zero itself: go a few ulps past it.
                    let past = t_new + direction * nudge;
                    if (past - t1) * direction <= 0.0 {
                        Some(past)
                    } else {
                        None
                    }
                } else {
                    None
                };
                match target {
                    Some(target) if refinements < MAX_EVENT_REFINEMENTS => {
                        // Redo the step, ending on (just past) the zero.
                        let own = if previous_rejected {
                            h_proposal.abs().min(h.abs())
                        } else {
                            h_proposal.abs()
                        };
                        let full_proposal = aiming.map_or(own, |(_, _, p)| p);
                        aiming = Some((target, refinements + 1, full_proposal));
                        h = target - t;
                        bump(&mut stats.rejected_steps, 1);
                        continue;
                    }
                    _ => landed = Some(i),
                }
            }
        }

        if err > 1.0 {
            bump(&mut stats.rejected_steps, 1);
            h /= (fac11 / SAFETY).min(1.0 / MIN_FACTOR);
            previous_rejected = true;
            aiming = None;
            continue;
        }

        // Accepted.
        bump(&mut stats.accepted_steps, 1);
        if !fsal_done {
            let [.., k12, _, _, _] = &mut k;
            system.derivatives(t_new, &y_new, k12);
            bump(&mut stats.derivative_evaluations, 1);
        }
        let [k0, .., k12, _, _, _] = &mut k;
        *k0 = *k12;
        t = t_new;
        y = y_new;
        if !all_finite(k0) {
            return Err(IntegrationError::NonFinite { t });
        }
        // Next step: this trial's proposal (no growth right after a rejection, as dop853.f),
        // or after a redo aimed at an event, that of the untruncated trial if larger.
        let mut next = if previous_rejected {
            h_proposal.abs().min(h.abs())
        } else {
            h_proposal.abs()
        };
        if let Some((_, _, full)) = aiming {
            next = next.max(full);
        }
        previous_rejected = false;
        aiming = None;
        h = next.min(hmax) * direction;

        for (i, (s, &g)) in sides.iter_mut().zip(&g_new).enumerate() {
            if landed == Some(i) {
                *s = -*s;
            } else if *s == 0 || sign(g) == -*s {
                *s = sign(g);
            }
        }
        observer.on_step(t, &y);
        if let Some(i) = landed {
            bump(&mut stats.events_located, 1);
            let rising = sides.get(i).copied().unwrap_or(0) > 0;
            observer.on_event(i, t, &y, rising);
            // Evaluate the derivative at the switch again, after the observer: a system whose
            // discrete mode (say a throttle held in a Cell) the observer switches at events
            // starts the next arc with the new mode.
            let [k0, ..] = &mut k;
            system.derivatives(t, &y, k0);
            bump(&mut stats.derivative_evaluations, 1);
            if !all_finite(k0) {
                return Err(IntegrationError::NonFinite { t });
            }
        }
        if last {
            return Ok((y, stats));
        }
    }
}

/// `steps` equal DOP853 steps from (t0, y0) to t1 (`steps >= 1`, no events: checked by the
/// caller), each reported to the observer. Step `i` spans `t0 + i h .. t0 + (i + 1) h`, the last
/// ending on `t1` exactly.
fn integrate_fixed<S: OdeSystem<N, E>, O: Observer<N>, const N: usize, const E: usize>(
    system: &S,
    t0: f64,
    y0: &[f64; N],
    t1: f64,
    steps: u32,
    observer: &mut O,
) -> Result<([f64; N], IntegrationStats), IntegrationError> {
    let mut stats = IntegrationStats::default();
    let mut k = [[0.0; N]; ALL_STAGES];
    let h = (t1 - t0) / f64::from(steps);
    let (mut t, mut y) = (t0, *y0);
    for i in 1..=steps {
        let t_new = if i == steps { t1 } else { t0 + f64::from(i) * h };
        {
            let [k0, ..] = &mut k;
            system.derivatives(t, &y, k0);
        }
        let y_new = advance(system, t, &y, t_new - t, &mut k);
        bump(&mut stats.derivative_evaluations, STAGES as u32);
        if !all_finite(&y_new) {
            return Err(IntegrationError::NonFinite { t });
        }
        bump(&mut stats.accepted_steps, 1);
        (t, y) = (t_new, y_new);
        observer.on_step(t, &y);
    }
    Ok((y, stats))
}
