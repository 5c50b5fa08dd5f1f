"""A plain-numpy second implementation of the transfer and rendezvous MDPs (docs/spec.md
sections 4 to 6), vectorised over N episodes.

It is written from the specification and the Rust source (`onboard/src/dynamics.rs`,
`onboard/src/features.rs`, `shared/src/orbit.rs`, `ground/core/src/env/mod.rs`) but shares no
numerical method with it, so that agreement between the two is evidence for both:

- thrusting steps: classical fixed-step RK4 (the Rust side: adaptive DOP853, rtol 1e-12), with a
  substep count per episode chosen from the osculating periapsis (see `_substeps_for`);
- coasting steps (throttle exactly 0): the exact two-body solution through the change of
  eccentric (hyperbolic) anomaly, solved by a bracketed Newton iteration (the Rust side:
  universal variables with a Laguerre-Conway iteration);
- the rendezvous body: its position from its elements by Kepler's equation at time k STEP
  (the Rust side: a universal-variable coast of its Cartesian state from t = 0).

Only numpy; no scipy, no numba. Units are canonical (AU, t* with mu = 1, mass in m0).

    env = NumpyVecEnv("transfer", scenarios, thrust, exhaust_speed)
    obs = env.reset()                                   # (N, obs_dim) float32
    obs, reward, done, features = env.step(actions)     # actions (N, 3) float32

`scenarios` are dicts as `lowthrust.draw_scenario` returns them: "initial" {"a", "e", "omega",
"nu"}, "target" {"a", "e", "omega"}, "target_nu0", "steps" (and optionally "problem").
"""

from __future__ import annotations

import math

import numpy as np

# --- shared/src/units.rs ----------------------------------------------------------------------
AU_M = 149_597_870_700.0
TIME_UNIT_S = 5_022_642.891_366_036
G0_M_S2 = 9.806_65
VELOCITY_UNIT_M_S = AU_M / TIME_UNIT_S
ACCELERATION_UNIT_M_S2 = AU_M / (TIME_UNIT_S * TIME_UNIT_S)
#: One environment step, 14 days, in t*.
STEP = 14.0 * 86_400.0 / TIME_UNIT_S

#: docs/spec.md section 5: below this norm of (a1, a2) the thrust is off.
MIN_DIRECTION_NORM = 1e-6
#: thesis Eq. 4.7-4.8 weights (w_p, w_v, w_u): `RewardWeights::default()`.
DEFAULT_REWARD = (0.2, 0.2, 0.02)
#: RK4 substeps per 14-day step for an orbit whose periapsis time scale is that of 1 AU.
DEFAULT_SUBSTEPS = 64

TRANSFER_FEATURES = 10
RENDEZVOUS_FEATURES = 22

TWO_PI = 2.0 * math.pi


def default_spacecraft(max_thrust_n=1.33, isp_s=3872.0, initial_mass_kg=3366.0):
    """(thrust T/m0 in AU/t*^2, exhaust speed in AU/t*) of a spacecraft; defaults: the MSR ERO
    of docs/spec.md section 1 (`Spacecraft::canonical`)."""
    thrust = max_thrust_n / initial_mass_kg / ACCELERATION_UNIT_M_S2
    exhaust_speed = isp_s * G0_M_S2 / VELOCITY_UNIT_M_S
    return thrust, exhaust_speed


def steps_for(a0, af):
    """docs/spec.md section 4: N = ceil(max(P0, Pf) / STEP - 1e-12)."""
    tof = max(TWO_PI * a0 * math.sqrt(a0), TWO_PI * af * math.sqrt(af))
    return int(math.ceil(tof / STEP - 1e-12))


# --- orbits (shared/src/orbit.rs, vectorised) ---------------------------------------------------
def polar_at(a, e, omega, nu):
    """Polar state (r, theta, v_r, v_theta) at true anomaly nu of the orbit (a, e, omega)."""
    p = a * (1.0 - e * e)
    s, c = np.sin(nu), np.cos(nu)
    k = np.sqrt(1.0 / p)
    return p / (1.0 + e * c), omega + nu, k * e * s, k * (1.0 + e * c)


def polar_to_cartesian(r, theta, v_r, v_theta):
    s, c = np.sin(theta), np.cos(theta)
    return r * c, r * s, v_r * c - v_theta * s, v_r * s + v_theta * c


def cartesian_at(a, e, omega, nu):
    """(x, y, vx, vy) at true anomaly nu."""
    return polar_to_cartesian(*polar_at(a, e, omega, nu))


def _bracketed_newton(fun, lo, hi, x, tol=4e-16, max_iter=200):
    """Root of the increasing functions `fun(x) -> (g, g')` (elementwise), one per element,
    inside the brackets [lo, hi]: Newton steps, a bisection whenever Newton would leave the
    bracket. Converged when the step is below `tol` (1 + |x|)."""
    lo, hi, x = lo.copy(), hi.copy(), x.copy()
    active = np.ones(x.shape, dtype=bool)
    for _ in range(max_iter):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            return x
        xi = x[idx]
        g, dg = fun(xi, idx)
        pos = g > 0.0
        hi[idx] = np.where(pos, np.minimum(hi[idx], xi), hi[idx])
        lo[idx] = np.where(pos, lo[idx], np.maximum(lo[idx], xi))
        with np.errstate(divide="ignore", invalid="ignore"):
            nxt = xi - g / dg
        out = ~((nxt > lo[idx]) & (nxt < hi[idx]))
        nxt = np.where(out, 0.5 * (lo[idx] + hi[idx]), nxt)
        done = (g == 0.0) | (np.abs(nxt - xi) <= tol * (1.0 + np.abs(xi))) | (hi[idx] - lo[idx] <= tol * (1.0 + np.abs(xi)))
        x[idx] = np.where(g == 0.0, xi, nxt)
        active[idx[done]] = False
    raise RuntimeError("Kepler iteration did not converge")


def solve_kepler(M, e):
    """Eccentric anomaly E with E - e sin E = M (0 <= e < 1), elementwise."""
    M, e = np.broadcast_arrays(np.asarray(M, float), np.asarray(e, float))
    M, e = M.ravel().copy(), e.ravel().copy()

    def fun(E, idx):
        return E - e[idx] * np.sin(E) - M[idx], 1.0 - e[idx] * np.cos(E)

    start = M + e * np.sin(M) / (1.0 - np.sin(M + e) + np.sin(M))
    start = np.clip(start, M - e, M + e)
    return _bracketed_newton(fun, M - e - 1e-12, M + e + 1e-12, start)


def orbit_state_at_time(a, e, omega, nu0, t):
    """(x, y, vx, vy) of the point that is at true anomaly nu0 at t = 0 on the orbit (a, e, omega),
    at time t: mean anomaly advanced by n t, Kepler's equation solved."""
    a, e, omega, nu0, t = (np.asarray(v, float) for v in np.broadcast_arrays(a, e, omega, nu0, t))
    shape = a.shape
    a, e, omega, nu0, t = (v.ravel() for v in (a, e, omega, nu0, t))
    E0 = 2.0 * np.arctan2(np.sqrt(1.0 - e) * np.sin(0.5 * nu0), np.sqrt(1.0 + e) * np.cos(0.5 * nu0))
    n = 1.0 / (a * np.sqrt(a))
    # The mean anomaly: the whole revolutions of n t removed first, so M stays in [-pi, pi].
    dM = n * t
    dM = dM - TWO_PI * np.round(dM / TWO_PI)
    M = E0 - e * np.sin(E0) + dM
    M = M - TWO_PI * np.round(M / TWO_PI)
    E = solve_kepler(M, e)
    nu = 2.0 * np.arctan2(np.sqrt(1.0 + e) * np.sin(0.5 * E), np.sqrt(1.0 - e) * np.cos(0.5 * E))
    return tuple(v.reshape(shape) for v in cartesian_at(a, e, omega, nu))


def kepler_coast(x, y, vx, vy, dt):
    """The exact two-body (mu = 1) state after dt from (x, y, vx, vy), elementwise, through the
    change of eccentric anomaly (elliptic) or hyperbolic anomaly (hyperbolic) and the Lagrange
    coefficients f, g. Near-parabolic states (|1 - r v^2 / 2| tiny) are refused."""
    x, y, vx, vy, dt = (np.asarray(v, float).ravel() for v in np.broadcast_arrays(x, y, vx, vy, dt))
    r0 = np.hypot(x, y)
    sigma0 = x * vx + y * vy
    alpha = 2.0 / r0 - (vx * vx + vy * vy)
    if np.any(np.abs(alpha * r0) < 1e-9):
        raise ValueError("near-parabolic coast: not handled by the numpy reference")
    f = np.empty_like(x)
    g = np.empty_like(x)
    fdot = np.empty_like(x)
    gdot = np.empty_like(x)

    ell = np.flatnonzero(alpha > 0.0)
    if ell.size:
        al, r0e, s0, t = alpha[ell], r0[ell], sigma0[ell], dt[ell]
        a = 1.0 / al
        sa = np.sqrt(a)
        n = al * np.sqrt(al)
        period = TWO_PI / n
        t = t - np.round(t / period) * period
        M = n * t
        ec = 1.0 - r0e / a  # e cos E0
        es = s0 / sa  # e sin E0

        def fun(d, idx):
            sd, cd = np.sin(d), np.cos(d)
            return d - ec[idx] * sd + es[idx] * (1.0 - cd) - M[idx], 1.0 - ec[idx] * cd + es[idx] * sd

        d = _bracketed_newton(fun, M - 2.0, M + 2.0, M.copy())
        sd, cd = np.sin(d), np.cos(d)
        omc = 2.0 * np.sin(0.5 * d) ** 2  # 1 - cos d without cancellation
        r = a * (1.0 - ec * cd + es * sd)
        f[ell] = 1.0 - a * omc / r0e
        g[ell] = t - a * sa * (d - sd)
        fdot[ell] = -sa * sd / (r * r0e)
        gdot[ell] = 1.0 - a * omc / r

    hyp = np.flatnonzero(alpha < 0.0)
    if hyp.size:
        al, r0h, s0, t = alpha[hyp], r0[hyp], sigma0[hyp], dt[hyp]
        b = -1.0 / al  # -a > 0
        sb = np.sqrt(b)
        n = (-al) * np.sqrt(-al)
        M = n * t
        ec = 1.0 + r0h / b  # e cosh H0
        es = s0 / sb  # e sinh H0

        def fun(d, idx):
            sh, ch = np.sinh(d), np.cosh(d)
            return es[idx] * (ch - 1.0) + ec[idx] * sh - d - M[idx], es[idx] * sh + ec[idx] * ch - 1.0

        # Bracket by doubling: G is increasing and G(0) = -M.
        lo = np.where(M > 0.0, 0.0, -1.0)
        hi = np.where(M > 0.0, 1.0, 0.0)
        for _ in range(80):
            glo = fun(lo, np.arange(lo.size))[0]
            ghi = fun(hi, np.arange(hi.size))[0]
            if np.all(glo <= 0.0) and np.all(ghi >= 0.0):
                break
            lo = np.where(glo > 0.0, 2.0 * lo - 1.0, lo)
            hi = np.where(ghi < 0.0, 2.0 * hi + 1.0, hi)
        d = _bracketed_newton(fun, lo, hi, 0.5 * (lo + hi))
        sh, ch = np.sinh(d), np.cosh(d)
        chm1 = 2.0 * np.sinh(0.5 * d) ** 2
        r = b * (es * sh + ec * ch - 1.0)
        f[hyp] = 1.0 - b * chm1 / r0h
        g[hyp] = t - b * sb * (sh - d)
        fdot[hyp] = -sb * sh / (r * r0h)
        gdot[hyp] = 1.0 - b * chm1 / r

    return f * x + g * vx, f * y + g * vy, fdot * x + gdot * vx, fdot * y + gdot * vy


# --- thrusting steps ----------------------------------------------------------------------------
def _rk4_polar_hold(Y, m0, tu, mdot, ar, at, duration, n):
    """RK4 with n equal substeps of the planar two-body problem with the thrust acceleration
    tu / m along the direction (ar, at) held in the local polar frame. Y: (4, K) [x, y, vx, vy];
    the mass is linear in time, m(t) = m0 + mdot t, so it is evaluated, not integrated."""
    h = duration / n
    half = 0.5 * h

    def deriv(Y, m):
        x, y = Y[0], Y[1]
        r2 = x * x + y * y
        ir = 1.0 / np.sqrt(r2)
        ir3 = ir / r2
        k = tu / m * ir  # thrust acceleration / r, so that k (ar x - at y) is its x component
        out = np.empty_like(Y)
        out[0] = Y[2]
        out[1] = Y[3]
        out[2] = k * (ar * x - at * y) - x * ir3
        out[3] = k * (ar * y + at * x) - y * ir3
        return out

    Y = Y.copy()
    for i in range(n):
        t0 = i * h
        m_a = m0 + mdot * t0
        m_b = m0 + mdot * (t0 + half)
        m_c = m0 + mdot * (t0 + h)
        k1 = deriv(Y, m_a)
        k2 = deriv(Y + half * k1, m_b)
        k3 = deriv(Y + half * k2, m_b)
        k4 = deriv(Y + h * k3, m_c)
        Y += (h / 6.0) * (k1 + 2.0 * (k2 + k3) + k4)
    return Y


def _substeps_for(x, y, vx, vy, base):
    """RK4 substeps for each state: `base` times the power of two that brings the step's
    length relative to the shortest time scale of the osculating orbit, its periapsis passage
    r_p^1.5 / sqrt(1 + e), back to what it is at 1 AU (a ratio up to 1.25 is left at `base`,
    so that orbits of 0.86 AU and beyond all share it)."""
    r = np.hypot(x, y)
    h = x * vy - y * vx
    ex = vy * h - x / r
    ey = -vx * h - y / r
    e = np.hypot(ex, ey)
    rp = np.minimum(h * h / (1.0 + e), r)
    scale = rp**1.5 / np.sqrt(1.0 + e)
    ratio = 1.0 / scale
    power = np.maximum(0, np.ceil(np.log2(ratio / 1.25))).astype(int)
    return base * (2 ** np.minimum(power, 12))


# --- the MDP ------------------------------------------------------------------------------------
class NumpyVecEnv:
    """N episodes of the transfer or rendezvous MDP stepped together.

    problem: "transfer" or "rendezvous" (a scenario kind name such as "transfer-hard" also
    works); scenarios: one dict per episode (see the module docstring); thrust: T/m0 in
    AU/t*^2; exhaust_speed: in AU/t*; reward: (w_p, w_v, w_u); substeps: RK4 substeps per
    thrusting 14-day step at the time scale of a 1 AU orbit (more where the osculating orbit's
    periapsis is closer to the Sun, see `_substeps_for`).

    `step` raises when an episode to be stepped is finished (as the Rust environments do), or
    when a step would empty the tank or leave the state unusable; the environment is then
    unchanged. `active` (bool (N,)) steps a subset only; the others keep their state and get
    reward 0.
    """

    def __init__(
        self,
        problem,
        scenarios,
        thrust=None,
        exhaust_speed=None,
        reward=DEFAULT_REWARD,
        substeps=DEFAULT_SUBSTEPS,
    ):
        problem = str(problem)
        if problem.startswith("transfer"):
            self.problem = "transfer"
        elif problem.startswith("rendezvous"):
            self.problem = "rendezvous"
        else:
            raise ValueError(f"unknown problem {problem!r}")
        if thrust is None or exhaust_speed is None:
            t, c = default_spacecraft()
            thrust = t if thrust is None else thrust
            exhaust_speed = c if exhaust_speed is None else exhaust_speed
        self.thrust = float(thrust)
        self.exhaust_speed = float(exhaust_speed)
        self.weights = tuple(float(w) for w in reward)
        self.substeps = int(substeps)
        self.obs_dim = TRANSFER_FEATURES if self.problem == "transfer" else RENDEZVOUS_FEATURES
        self._set_scenarios(list(scenarios), np.ones(len(scenarios), dtype=bool), first=True)
        self.num_envs = len(scenarios)
        self.state = np.full((self.num_envs, 5), np.nan)
        self.k = np.zeros(self.num_envs, dtype=np.int64)
        self.throttle = np.zeros(self.num_envs)
        self.dr = np.full(self.num_envs, np.nan)
        self.dv = np.full(self.num_envs, np.nan)
        self.features = np.full((self.num_envs, self.obs_dim), np.nan)
        self._reset_ever = False

    # scenarios -------------------------------------------------------------------------------
    def _set_scenarios(self, scenarios, mask, first=False):
        if len(scenarios) == 0:
            raise ValueError("at least one scenario")
        cols = {
            name: np.array([float(s["initial"][key]) for s in scenarios])
            for name, key in (("a0", "a"), ("e0", "e"), ("om0", "omega"), ("nu0", "nu"))
        }
        cols.update(
            {
                name: np.array([float(s["target"][key]) for s in scenarios])
                for name, key in (("af", "a"), ("ef", "e"), ("omf", "omega"))
            }
        )
        cols["nuf0"] = np.array([float(s.get("target_nu0", 0.0)) for s in scenarios])
        cols["steps"] = np.array([int(s["steps"]) for s in scenarios], dtype=np.int64)
        for s in scenarios:
            if "problem" in s and s["problem"] != self.problem:
                raise ValueError(f"a {s['problem']} scenario given to the {self.problem} environment")
        if np.any(cols["steps"] <= 0):
            raise ValueError("every scenario needs steps >= 1")
        for name, col in cols.items():
            if first:
                setattr(self, name, col)
            else:
                getattr(self, name)[mask] = col[mask]
        if self.problem == "rendezvous":
            self._body_table(mask, first)

    def _body_table(self, mask, first):
        """The body's Cartesian state at every step k = 0..N of the masked episodes: (N_env,
        K+1, 4), K the longest episode."""
        kmax = int(self.steps.max())
        if first or not hasattr(self, "_body") or self._body.shape[1] < kmax + 1:
            old = getattr(self, "_body", None)
            self._body = np.full((self.steps.size, kmax + 1, 4), np.nan)
            if old is not None and not first:
                self._body[:, : old.shape[1]] = old
            mask = np.ones(self.steps.size, dtype=bool) if first or old is None else mask
        idx = np.flatnonzero(mask)
        k = np.arange(kmax + 1)
        t = k[None, :] * STEP
        pick = lambda v: v[idx][:, None]  # noqa: E731
        xb = orbit_state_at_time(pick(self.af), pick(self.ef), pick(self.omf), pick(self.nuf0), t)
        self._body[idx] = np.stack(xb, axis=-1)

    # features and reward -------------------------------------------------------------------
    def _features(self, state, k, idx):
        """f64 features (len(idx), obs_dim) of `state` (len(idx), 5) at step indices `k`."""
        x, y, vx, vy, m = state.T
        r = np.hypot(x, y)
        theta = np.arctan2(y, x)
        ttg = (self.steps[idx] - k).clip(min=0).astype(float) * STEP
        if self.problem == "transfer":
            v_r = (x * vx + y * vy) / r
            v_t = (x * vy - y * vx) / r
            r_t, _, v_r_t, v_t_t = polar_at(self.af[idx], self.ef[idx], self.omf[idx], theta - self.omf[idx])
            return np.stack([r, np.cos(theta), np.sin(theta), v_r, v_t, m, r_t, v_r_t, v_t_t, ttg], axis=1)
        xb, yb, vxb, vyb = self._body[idx, k].T
        rb = np.hypot(xb, yb)
        thb = np.arctan2(yb, xb)
        dx, dy, dvx, dvy = xb - x, yb - y, vxb - vx, vyb - vy
        return np.stack(
            [
                r, np.cos(theta), np.sin(theta), rb, np.cos(thb), np.sin(thb),
                x, y, vx, vy, xb, yb, vxb, vyb, dx, dy, dvx, dvy,
                np.hypot(dx, dy), np.hypot(dvx, dvy), ttg, m,
            ],
            axis=1,
        )

    def _residuals(self, f):
        if self.problem == "transfer":
            return np.abs(f[:, 6] - f[:, 0]), np.hypot(f[:, 7] - f[:, 3], f[:, 8] - f[:, 4])
        return f[:, 18], f[:, 19]

    def _reward(self, dr, dv, u):
        wp, wv, wu = self.weights
        return np.expm1(-wp * dr * dr) + np.expm1(-wv * dv * dv) - wu * u

    # API -------------------------------------------------------------------------------------
    @property
    def done(self):
        return self.k >= self.steps

    def reset(self, mask=None, scenarios=None):
        """Starts the masked episodes (default: all) at their initial state, m = 1, step 0;
        `scenarios` (a list of N dicts) first replaces the masked episodes' scenarios.
        Returns every episode's observation (N, obs_dim) float32."""
        mask = np.ones(self.num_envs, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
        if mask.shape != (self.num_envs,):
            raise ValueError("mask must be (num_envs,)")
        if not self._reset_ever and not mask.all():
            raise ValueError("the first reset must reset every episode")
        if scenarios is not None:
            if len(scenarios) != self.num_envs:
                raise ValueError("scenarios must have num_envs entries")
            self._set_scenarios(list(scenarios), mask)
        idx = np.flatnonzero(mask)
        x, y, vx, vy = cartesian_at(self.a0[idx], self.e0[idx], self.om0[idx], self.nu0[idx])
        state = np.stack([x, y, vx, vy, np.ones(idx.size)], axis=1)
        self.state[idx] = state
        self.k[idx] = 0
        self.throttle[idx] = 0.0
        self.features[idx] = self._features(state, self.k[idx], idx)
        self.dr[idx], self.dv[idx] = self._residuals(self.features[idx])
        self._reset_ever = True
        return self.features.astype(np.float32)

    @staticmethod
    def decode_actions(actions):
        """`onboard::features::decode_action`, vectorised: (throttle, alpha_r, alpha_theta) f64.
        Clamped in f32 as the network emits it; a non-finite action or |(a1, a2)| < 1e-6: thrust
        off (throttle 0, direction (0, 1))."""
        a = np.asarray(actions, dtype=np.float32)
        if a.ndim != 2 or a.shape[1] != 3:
            raise ValueError("actions must be (N, 3)")
        finite = np.isfinite(a).all(axis=1)
        a = np.clip(a, np.float32(-1.0), np.float32(1.0)).astype(np.float64)
        norm = np.hypot(a[:, 1], a[:, 2])
        off = ~finite | ~(norm >= MIN_DIRECTION_NORM)
        safe = np.where(off, 1.0, norm)
        throttle = np.where(off, 0.0, (a[:, 0] + 1.0) * 0.5)
        alpha_r = np.where(off, 0.0, a[:, 1] / safe)
        alpha_t = np.where(off, 1.0, a[:, 2] / safe)
        return throttle, alpha_r, alpha_t

    def propagate(self, state, throttle, alpha_r, alpha_t, duration=STEP):
        """`onboard::dynamics::propagate` for a batch: (K, 5) states -> (K, 5) states."""
        out = np.empty_like(state)
        coast = throttle == 0.0
        ci = np.flatnonzero(coast)
        if ci.size:
            s = state[ci]
            out[ci, :4] = np.stack(kepler_coast(s[:, 0], s[:, 1], s[:, 2], s[:, 3], duration), axis=1)
            out[ci, 4] = s[:, 4]
        ti = np.flatnonzero(~coast)
        if ti.size:
            s = state[ti]
            u = throttle[ti]
            mdot = -self.thrust * u / self.exhaust_speed
            m_end = s[:, 4] - self.thrust * u * duration / self.exhaust_speed
            if np.any(~(m_end > 0.0)):
                raise ValueError(f"propellant runs out during the step (episodes {ti[~(m_end > 0.0)].tolist()})")
            n = _substeps_for(s[:, 0], s[:, 1], s[:, 2], s[:, 3], self.substeps)
            for nn in np.unique(n):
                g = np.flatnonzero(n == nn)
                Y = _rk4_polar_hold(
                    s[g, :4].T, s[g, 4], self.thrust * u[g], mdot[g], alpha_r[ti[g]], alpha_t[ti[g]], duration, int(nn)
                )
                out[ti[g], :4] = Y.T
                out[ti[g], 4] = s[g, 4] + mdot[g] * duration
        return out

    def step(self, actions, active=None):
        """One 14-day step of every (active) episode. Returns (obs (N, obs_dim) float32, reward
        (N,) float64, done (N,) bool, features (N, obs_dim) float64)."""
        if not self._reset_ever:
            raise ValueError("step called before reset")
        active = np.ones(self.num_envs, dtype=bool) if active is None else np.asarray(active, dtype=bool)
        actions = np.asarray(actions, dtype=np.float32)
        if actions.shape != (self.num_envs, 3):
            raise ValueError(f"actions of shape {actions.shape} for {self.num_envs} episodes")
        idx = np.flatnonzero(active)
        over = idx[self.done[idx]]
        if over.size:
            raise ValueError(f"step called after the terminal step of episodes {over.tolist()}; reset first")
        throttle, alpha_r, alpha_t = self.decode_actions(actions[idx])
        with np.errstate(all="ignore"):
            new = self.propagate(self.state[idx], throttle, alpha_r, alpha_t)
        bad = ~(np.isfinite(new).all(axis=1) & (np.hypot(new[:, 0], new[:, 1]) > 0.0) & (new[:, 4] > 0.0))
        if bad.any():
            raise ValueError(f"propagation failed for episodes {idx[bad].tolist()}")
        k = self.k[idx] + 1
        f = self._features(new, k, idx)
        dr, dv = self._residuals(f)
        rew = np.zeros(self.num_envs)
        rew[idx] = self._reward(dr, dv, throttle)
        self.state[idx] = new
        self.k[idx] = k
        self.throttle[idx] = throttle
        self.features[idx] = f
        self.dr[idx], self.dv[idx] = dr, dv
        return self.features.astype(np.float32), rew, self.done.copy(), self.features.copy()
