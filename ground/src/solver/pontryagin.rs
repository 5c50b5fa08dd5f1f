//! Pontryagin's necessary conditions for the mass-optimal problem with the energy-to-fuel
//! homotopy (SPEC section 3, thesis Chapter 3).
//!
//! State + costate y = (r, v, m, lambda_r, lambda_v, lambda_m), 10 components. The right-hand
//! side is written once, generic over a dual-number type, so the variational equations
//! (sensitivity of y to the initial costates) come out exact by forward-mode differentiation of
//! the very same code instead of a hand-derived Jacobian that could drift from it.

use nalgebra::{Const, SVector};
use num_dual::{Derivative, DualNum, DualVec64};
use onboard::integrator::{OdeSystem, MAX_EVENTS};
use shared::spacecraft::CanonicalSpacecraft;

/// State + costate length.
pub const Y_LEN: usize = 10;
/// Shooting variables that the sensitivity is taken against: the five initial costates.
pub const SENS_COLS: usize = 5;
/// State + costate + 10x5 sensitivity matrix (column-major after the first 10).
pub const YS_LEN: usize = Y_LEN + Y_LEN * SENS_COLS;

/// Indices into y.
pub mod idx {
    pub const R: usize = 0;
    pub const V: usize = 2;
    pub const M: usize = 4;
    pub const LR: usize = 5;
    pub const LV: usize = 7;
    pub const LM: usize = 9;
}

/// The spacecraft and the homotopy parameter eps of the running cost L = u - eps u (1 - u).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OptimalControlParams {
    pub spacecraft: CanonicalSpacecraft,
    pub eps: f64,
}

/// Switching function rho = lambda_m + c |lambda_v| / m - 1.
pub fn switching_function<D: DualNum<Primitive = f64> + Copy>(y: &[D; Y_LEN], exhaust_speed: f64) -> D {
    let lv = (y[idx::LV] * y[idx::LV] + y[idx::LV + 1] * y[idx::LV + 1]).sqrt();
    y[idx::LM] + lv * exhaust_speed / y[idx::M] - 1.0
}

/// Smoothed optimal throttle (SPEC section 3): 1 above +eps, 0 below -eps, linear between.
/// With eps = 0 it is the bang-bang law. Derivatives flow through the linear part only.
pub fn optimal_throttle<D: DualNum<Primitive = f64> + Copy>(rho: D, eps: f64) -> D {
    let r = rho.re();
    if eps <= 0.0 {
        return D::from(if r > 0.0 { 1.0 } else { 0.0 });
    }
    if r > eps {
        D::from(1.0)
    } else if r < -eps {
        D::from(0.0)
    } else {
        (rho / eps + 1.0) * 0.5
    }
}

/// dy/dt of the state-costate system with the optimal control substituted.
pub fn state_costate_rhs<D: DualNum<Primitive = f64> + Copy>(y: &[D; Y_LEN], p: &OptimalControlParams) -> [D; Y_LEN] {
    let (t_max, c) = (p.spacecraft.thrust, p.spacecraft.exhaust_speed);
    let (x, yy) = (y[idx::R], y[idx::R + 1]);
    let (vx, vy, m) = (y[idx::V], y[idx::V + 1], y[idx::M]);
    let (lrx, lry) = (y[idx::LR], y[idx::LR + 1]);
    let (lvx, lvy) = (y[idx::LV], y[idx::LV + 1]);
    let r2 = x * x + yy * yy;
    let r = r2.sqrt();
    let r3 = r2 * r;
    let r5 = r3 * r2;
    let lv = (lvx * lvx + lvy * lvy).sqrt();
    let u = optimal_throttle(switching_function(y, c), p.eps);
    // Primer vector: thrust opposite lambda_v.
    let acc = u * t_max / m;
    let (ax, ay) = (-acc * lvx / lv, -acc * lvy / lv);
    let r_dot_lv = x * lvx + yy * lvy;
    [
        vx,
        vy,
        -x / r3 + ax,
        -y[idx::R + 1] / r3 + ay,
        -u * t_max / c,
        lvx / r3 - x * r_dot_lv * 3.0 / r5,
        lvy / r3 - yy * r_dot_lv * 3.0 / r5,
        -lrx,
        -lry,
        -u * t_max * lv / (m * m),
    ]
}

/// The Hamiltonian for an arbitrary control (u, alpha): used by the tests to check the costate
/// equations and the optimal control independently of the code above.
pub fn hamiltonian(y: &[f64; Y_LEN], u: f64, alpha: [f64; 2], p: &OptimalControlParams) -> f64 {
    let (t_max, c) = (p.spacecraft.thrust, p.spacecraft.exhaust_speed);
    let r = y[0].hypot(y[1]);
    let g = [-y[0] / r.powi(3), -y[1] / r.powi(3)];
    let m = y[idx::M];
    t_max / c * (u - p.eps * u * (1.0 - u))
        + y[idx::LR] * y[idx::V]
        + y[idx::LR + 1] * y[idx::V + 1]
        + y[idx::LV] * (g[0] + t_max * u * alpha[0] / m)
        + y[idx::LV + 1] * (g[1] + t_max * u * alpha[1] / m)
        - y[idx::LM] * t_max * u / c
}

/// The state-costate ODE, stepping exactly onto the throttle switches rho = +-eps.
#[derive(Debug, Clone, Copy)]
pub struct StateCostate(pub OptimalControlParams);

impl OdeSystem<Y_LEN> for StateCostate {
    fn derivatives(&self, _t: f64, y: &[f64; Y_LEN], dydt: &mut [f64; Y_LEN]) {
        *dydt = state_costate_rhs(y, &self.0);
    }

    fn events(&self, _t: f64, y: &[f64; Y_LEN]) -> [f64; MAX_EVENTS] {
        switch_events(y, &self.0)
    }
}

fn switch_events(y: &[f64; Y_LEN], p: &OptimalControlParams) -> [f64; MAX_EVENTS] {
    let rho = switching_function(y, p.spacecraft.exhaust_speed);
    [rho - p.eps, rho + p.eps]
}

/// State-costate plus the sensitivity matrix d y / d lambda_0 (10 x 5), by forward-mode duals.
#[derive(Debug, Clone, Copy)]
pub struct StateCostateSensitivity(pub OptimalControlParams);

type Dual5 = DualVec64<Const<SENS_COLS>>;

impl StateCostateSensitivity {
    /// Initial condition: y0 with the identity on the costate rows of the sensitivity.
    pub fn initial(y0: &[f64; Y_LEN]) -> [f64; YS_LEN] {
        let mut ys = [0.0; YS_LEN];
        ys[..Y_LEN].copy_from_slice(y0);
        for k in 0..SENS_COLS {
            ys[Y_LEN + k * Y_LEN + idx::LR + k] = 1.0;
        }
        ys
    }

    /// Sensitivity entry d y_i / d lambda0_k.
    pub fn sensitivity(ys: &[f64; YS_LEN], i: usize, k: usize) -> f64 {
        ys[Y_LEN + k * Y_LEN + i]
    }
}

impl OdeSystem<YS_LEN> for StateCostateSensitivity {
    fn derivatives(&self, _t: f64, ys: &[f64; YS_LEN], dydt: &mut [f64; YS_LEN]) {
        // Seed each component with its row of the sensitivity matrix: the dual parts of f then
        // are J(y) * Phi, the right-hand side of the variational equations.
        let y: [Dual5; Y_LEN] = core::array::from_fn(|i| {
            let row = SVector::<f64, SENS_COLS>::from_fn(|k, _| ys[Y_LEN + k * Y_LEN + i]);
            Dual5::new(ys[i], Derivative::some(row))
        });
        let f = state_costate_rhs(&y, &self.0);
        for (i, fi) in f.iter().enumerate() {
            dydt[i] = fi.re;
            let d = fi.eps.unwrap_generic(Const::<SENS_COLS>, Const::<1>);
            for k in 0..SENS_COLS {
                dydt[Y_LEN + k * Y_LEN + i] = d[k];
            }
        }
    }

    fn events(&self, _t: f64, ys: &[f64; YS_LEN]) -> [f64; MAX_EVENTS] {
        let y: [f64; Y_LEN] = core::array::from_fn(|i| ys[i]);
        switch_events(&y, &self.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use onboard::integrator::{integrate, Tolerances};
    use shared::spacecraft::Spacecraft;

    fn params(eps: f64) -> OptimalControlParams {
        OptimalControlParams {
            spacecraft: Spacecraft::MSR_ERO.canonical().unwrap(),
            eps,
        }
    }

    /// A state away from the Sun with costates that put rho inside (-eps, eps) for eps = 0.5.
    fn sample_y() -> [f64; Y_LEN] {
        [0.9, 0.5, -0.4, 0.8, 0.85, 0.3, -0.2, -0.25, 0.4, 0.1]
    }

    fn optimal_control(y: &[f64; Y_LEN], p: &OptimalControlParams) -> (f64, [f64; 2]) {
        let u = optimal_throttle(switching_function(y, p.spacecraft.exhaust_speed), p.eps);
        let lv = y[idx::LV].hypot(y[idx::LV + 1]);
        (u, [-y[idx::LV] / lv, -y[idx::LV + 1] / lv])
    }

    #[test]
    fn costate_equations_are_minus_the_gradient_of_the_hamiltonian() {
        for eps in [0.5, 1.0, 0.0] {
            let p = params(eps);
            let y = sample_y();
            let (u, alpha) = optimal_control(&y, &p);
            let f = state_costate_rhs(&y, &p);
            let h = 1e-6;
            for i in 0..Y_LEN {
                let (mut yp, mut ym) = (y, y);
                yp[i] += h;
                ym[i] -= h;
                // Control frozen at its optimum (envelope theorem).
                let dh = (hamiltonian(&yp, u, alpha, &p) - hamiltonian(&ym, u, alpha, &p)) / (2.0 * h);
                // dx/dt = dH/dlambda, dlambda/dt = -dH/dx.
                let expect = if i < 5 { -dh } else { dh };
                let j = if i < 5 { i + 5 } else { i - 5 };
                assert!(
                    (f[j] - expect).abs() < 1e-8,
                    "eps {eps} component {j}: {} vs {expect}",
                    f[j]
                );
            }
        }
    }

    #[test]
    fn optimal_control_minimises_the_hamiltonian() {
        for eps in [1.0, 0.3, 0.05, 0.0] {
            let p = params(eps);
            for s in 0..20 {
                let mut y = sample_y();
                y[idx::LM] = -0.6 + 0.06 * f64::from(s); // sweep rho across both switches
                let (u_opt, a_opt) = optimal_control(&y, &p);
                let h_opt = hamiltonian(&y, u_opt, a_opt, &p);
                for iu in 0..=20 {
                    for ia in 0..36 {
                        let u = f64::from(iu) / 20.0;
                        let ang = f64::from(ia) * 10f64.to_radians();
                        let h = hamiltonian(&y, u, [ang.cos(), ang.sin()], &p);
                        assert!(h >= h_opt - 1e-14, "eps {eps}: u {u} beats u* {u_opt}");
                    }
                }
            }
        }
    }

    #[test]
    fn smoothed_throttle_is_continuous_at_the_switches() {
        for eps in [1.0, 0.1, 1e-4] {
            for edge in [-eps, eps] {
                let below: f64 = optimal_throttle(edge - 1e-12 * eps, eps);
                let above: f64 = optimal_throttle(edge + 1e-12 * eps, eps);
                assert!((below - above).abs() < 1e-11, "jump at {edge}");
            }
            assert_eq!(optimal_throttle(0.0, eps), 0.5);
        }
    }

    #[test]
    fn sensitivity_matrix_matches_finite_differences() {
        let p = params(0.5);
        let y0 = [1.0, 0.0, 0.0, 1.0, 1.0, 0.2, 0.1, -0.3, -0.6, 0.05];
        let tol = Tolerances {
            relative: 1e-12,
            absolute: 1e-13,
            ..Tolerances::default()
        };
        let tf = 2.5;
        let (ys, _) = integrate(
            &StateCostateSensitivity(p),
            0.0,
            &StateCostateSensitivity::initial(&y0),
            tf,
            &tol,
        )
        .unwrap();
        // The plain system and the augmented one agree on y.
        let (y_plain, _) = integrate(&StateCostate(p), 0.0, &y0, tf, &tol).unwrap();
        for i in 0..Y_LEN {
            assert!((ys[i] - y_plain[i]).abs() < 1e-9);
        }
        let h = 1e-6;
        for k in 0..SENS_COLS {
            let (mut yp, mut ym) = (y0, y0);
            yp[idx::LR + k] += h;
            ym[idx::LR + k] -= h;
            let (fp, _) = integrate(&StateCostate(p), 0.0, &yp, tf, &tol).unwrap();
            let (fm, _) = integrate(&StateCostate(p), 0.0, &ym, tf, &tol).unwrap();
            for i in 0..Y_LEN {
                let fd = (fp[i] - fm[i]) / (2.0 * h);
                let s = StateCostateSensitivity::sensitivity(&ys, i, k);
                assert!(
                    (s - fd).abs() < 1e-5 * (1.0 + fd.abs()),
                    "d y{i} / d lambda{k}: {s} vs {fd}"
                );
            }
        }
    }
}
