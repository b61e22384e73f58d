"""The effects catalog as fitted measurement-model terms, and their held-out evaluation.

This is the engine of `accelcal diagnose` (accelcal_station/diagnose.py).  A model is
the simulator configuration's enabled effects plus the candidates added to them; every
effect is a parametric term in one of two views of the data, and the noise floor is
the variance the simulator predicts for every residual.

Static view (pose means).  The calibrated output of pose i is linear in the
parameters, ``u_i = A_i theta + b_i`` (AN4399 Eqns 46 and 67 extended):

  with references     r_i = gamma ref_i - u_i         3 rows, weighted least squares
  without (norm only) r_i = |u_i| - gamma - d_i theta 1 row, Levenberg-Marquardt (nine-position paper)

where ``gamma`` is the configured local gravity in standard g.  Terms, per channel c
(g the reading in nominal g, dT = T - T_mid, t the capture time):

  gain         W diagonal: u_c += w_c g_c
  cross_axis   W full (norm only: symmetric -- a rotation keeps the norm, so its
               antisymmetric part is invisible)
  offset       u_c += v_c
  cubic        u_c += Gamma_c g_c^3                       (AN4399 Eqn 67: inverts the sim exactly)
  quadratic    u_c += q_c g_c^2                           (inverts the sim's square term exactly)
  temperature  u_c += (a_c g_c + b_c) dT  (+ (a2_c g_c + b2_c) dT^2 at three or more temperatures)
  drift        u_c -= a_c (1 - exp(-t / tau)) + b_c t / T (warm-up and trend; tau on a grid; raw only)
  gravity      gamma -> gamma (1 + delta)                 (degenerate whenever a gain is fitted)

Time view (raw captures only).  Each capture is cut into blocks; a block's mean minus
its capture's mean is ``e_kb = F_kb theta`` plus noise (3 rows per block):

  drift        the same d(t) as above, within the capture
  settling     x(t) += a_k exp(-(t - t0_k) / tau): tau shared, the amplitude a_k a random
               effect per capture and axis (a ~ N(0, psi^2)), because automatic segmentation
               trims each capture's transient by a different amount; the transient's mean
               is removed from the static view too (see evaluate)

Spread view (std and n, or raw samples).  Each pose's within-pose variance against the
per-sample variance the model predicts; scored, not part of the headline gap.

Floor.  The variance of a pose mean of n samples with white noise sigma and
quantization step q is ``B + (sigma^2 + q^2/12 - B) / n`` per axis, where
``B = sum_k q^2 / (2 pi^2 k^2) exp(-4 pi^2 k^2 sigma^2 / q^2)`` is the part of the
quantization error that averaging cannot remove (the Fourier series of the
rounding error smoothed by the noise; B = q^2/12 without noise, 0 when the noise
dithers).  Pose scatter s (rad, per rotation axis) adds ``s^2 (1 - ref_c^2)``.
Stochastic candidates refit these from the data instead of taking them from the
configuration: ``noise`` (sigma from the poses' std or raw first differences),
``quantization`` (q from the raw samples' value grid), ``pose_error`` (s by maximum
likelihood on training residuals).

Held-out evaluation.  Poses (captures) are split into K folds; each fold's
residuals come from a fit on the others, and their variance is the floor plus the
fit's own prediction variance ``a^T (A^T V^-1 A)^-1 a``, so a model that explains
the data scores a held-out gap of 1 (with raw captures: the RMS of the static and time
views' gaps).  The score of a model is its Gaussian log predictive density per
(pose, axis) -- a proper score: it rewards neither inflated nor shrunken variance.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

TAU_DRIFT_S = np.geomspace(10.0, 1000.0, 13)
TAU_SETTLE_S = np.geomspace(0.02, 3.0, 19)
MAX_FOLDS = 8
T_SCALE_C = 25.0  # dT in units of 25 C keeps the design well scaled
_SYM = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))
_S2_GRID = np.concatenate([[0.0], np.geomspace(1e-12, 1e-2, 121)])  # pose scatter variance, rad^2
_PSI2_GRID = np.concatenate([[0.0], np.geomspace(1e-14, 1e-2, 73)])  # settling amplitude variance, g^2


# -- data ----------------------------------------------------------------------------------

@dataclass
class Capture:
    """Raw samples of one static pose: t (n,) seconds since its file started, x (n, 3) in data units."""

    t: np.ndarray
    x: np.ndarray
    per_g: float  # data units per nominal g


@dataclass
class GapData:
    """Real (or simulated) data in nominal g, ready for the diagnosis.

    g: (P, 3) pose means; ref: (P, 3) expected output in g or None (norm-only);
    n: (P,) samples per mean (``n_known`` False: assumed); std_g: (P, 3) per-sample std or None;
    temp_c: (P,) or None; file: (P,) index into ``sources``; captures: one per pose (raw logs) or None.
    """

    names: list[str]
    g: np.ndarray
    ref: np.ndarray | None
    n: np.ndarray
    n_known: bool
    std_g: np.ndarray | None
    temp_c: np.ndarray | None
    file: np.ndarray
    captures: list[Capture] | None
    rate_hz: float | None
    sources: list[str]
    notes: list[str] = field(default_factory=list)
    counts_per_g: list = field(default_factory=list)  # per file: counts per g used (None: not counts)
    zero_g: np.ndarray | None = None  # (3,) the zero-g reading of the baseline fit (centres cubic and square)

    @property
    def P(self) -> int:
        return len(self.g)

    @property
    def norm_only(self) -> bool:
        return self.ref is None

    @property
    def n_temps(self) -> int:
        return 0 if self.temp_c is None else len(np.unique(np.round(self.temp_c / 2.0)))

    def folds(self) -> np.ndarray:
        """Fold of every pose: round-robin over the recorded order (spreads designs, temperatures, time)."""
        return np.arange(self.P) % self.n_folds

    @property
    def n_folds(self) -> int:
        """Leave-one-out up to 12 poses (every pose counts), else MAX_FOLDS folds."""
        return self.P if self.P <= 12 else MAX_FOLDS


@dataclass
class Floor:
    """What the simulator says the noise is: per-sample sigma (3,) g, quantization step q g, pose scatter s rad."""

    sigma_g: np.ndarray
    q_g: float
    scatter_rad: float
    gamma: float  # configured local gravity in standard g
    sim_sigma_g: np.ndarray | None = None  # the simulator's own sigma, when sigma_g was measured from the data
    source: str = "simulator noise and quantization"
    sim_q_g: float | None = None  # the simulator's own LSB, when q_g was measured from the data


def bias_var(sigma, q) -> np.ndarray:
    """B: variance (over poses) of the quantization error a mean of n samples keeps (module doc)."""
    sigma, q = np.broadcast_arrays(np.asarray(sigma, float), np.asarray(q, float))
    k = np.arange(1, 201)  # enough terms for B -> q^2/12 as sigma -> 0
    qs = np.where(q > 0, q, 1.0)[..., None]
    terms = qs**2 / (2 * np.pi**2 * k**2) * np.exp(-4 * np.pi**2 * k**2 * sigma[..., None]**2 / qs**2)
    return np.where(q > 0, terms.sum(-1), 0.0)


def random_var(sigma, q) -> np.ndarray:
    """Per-sample variance around a pose's mean: sigma^2 + q^2/12 - B."""
    sigma, q = np.broadcast_arrays(np.asarray(sigma, float), np.asarray(q, float))
    return sigma**2 + q**2 / 12.0 - bias_var(sigma, q)


def within_spread(sigma, q) -> np.ndarray:
    """Variance, over a pose's position on the quantization grid, of its within-pose variance.

    w(x) = Var[Q(x + noise)] for x uniform in one step (numerically, on 64 positions);
    0 without quantization.  Heavy quantization (sigma << q) makes w swing from 0 (x mid-step)
    to about q^2/4 (x on a step edge), which a sampling variance alone would not predict.
    """
    from scipy.special import ndtr

    sigma, q = np.broadcast_arrays(np.asarray(sigma, float), np.asarray(q, float))
    out = np.zeros(sigma.shape)
    for idx in np.ndindex(sigma.shape):
        s, h = float(sigma[idx]), float(q[idx])
        if h <= 0:
            continue
        x = (np.arange(64) + 0.5) / 64 * h
        K = int(np.ceil(6 * s / h)) + 1
        k = np.arange(-K, K + 1)[:, None] * h
        if s > 0:
            pk = ndtr((k + h / 2 - x) / s) - ndtr((k - h / 2 - x) / s)
        else:
            pk = (np.abs(k - x) < h / 2).astype(float)
        m = np.sum(pk * k, axis=0)
        w = np.sum(pk * k**2, axis=0) - m**2
        out[idx] = np.var(w)
    return out


def mean_var(sigma, q, n) -> np.ndarray:
    """Variance of a mean of n samples: B + (sigma^2 + q^2/12 - B) / n (module doc)."""
    return bias_var(sigma, q) + random_var(sigma, q) / n


def sigma_from_within(w2, q) -> np.ndarray:
    """White-noise sigma whose within-pose variance (with quantization q) is w2: solves random_var = w2."""
    w2 = np.asarray(w2, float)
    s2 = np.maximum(w2 - np.asarray(q) ** 2 / 12.0, 0.0)
    for _ in range(30):
        s2 = np.maximum(w2 - np.asarray(q) ** 2 / 12.0 + bias_var(np.sqrt(s2), q), 0.0)
    return np.sqrt(s2)


def value_step(x: np.ndarray) -> float:
    """The grid the values sit on (their LSB) in data units, 0 when they are not on one."""
    v = np.unique(np.asarray(x, float).ravel())
    if len(v) < 2:
        return 0.0
    if np.all(v == np.round(v)):
        return float(np.gcd.reduce(np.diff(v).astype(np.int64)))
    d = np.diff(v)
    step = float(d.min())
    on_grid = np.abs((v - v[0]) / step - np.round((v - v[0]) / step)) < 1e-6
    return step if step > 0 and np.all(on_grid) else 0.0


# -- time view data --------------------------------------------------------------------------

@dataclass
class TimeData:
    """Block rows of the raw captures (see module doc); every array is per row unless noted."""

    e: np.ndarray  # (R,) block mean minus capture mean, g
    axis: np.ndarray  # (R,)
    unit: np.ndarray  # (R,) pose index
    inv_m: np.ndarray  # (R,) 1/m_b - 1/n_k
    t_in: np.ndarray  # (R,) block mid time since the capture started, s
    drift1: np.ndarray  # (Gw, R) block-minus-capture mean of 1 - exp(-t/tau)
    drift2: np.ndarray  # (R,) same of t / T
    settle: np.ndarray  # (Gs, R) same of exp(-(t - t0)/tau)
    step_unit: np.ndarray  # (P, 3) direction of the last move: mean reading minus the previous capture's
    cap_drift1: np.ndarray  # (Gw, P) capture mean of 1 - exp(-t/tau)
    cap_drift2: np.ndarray  # (P,)
    cap_settle: np.ndarray  # (Gs, P) capture mean of exp(-(t - t0)/tau)
    diff_var: np.ndarray  # (P, 3) half the variance of first differences (white-noise variance), g^2
    step_units: np.ndarray  # (P,) value grid (LSB) of each capture, data units (0: none found)
    per_g: np.ndarray  # (P,) data units per g of each capture

    def lsb_g(self, use: np.ndarray) -> float:
        """The LSB of the captures selected by ``use``: gcd of their integer value grids, in g."""
        st = self.step_units[use]
        st = st[st > 0]
        if not st.size:
            return 0.0
        step = float(np.gcd.reduce(st.astype(np.int64))) if np.all(st == np.round(st)) else float(st.min())
        return step / float(np.median(self.per_g[use]))


def time_data(data: GapData) -> TimeData | None:
    """Cut every capture into blocks (at most 8, at least 12 samples each)."""
    caps = data.captures
    if caps is None:
        return None
    P = data.P
    span = np.zeros(len(data.sources))
    for k, c in enumerate(caps):
        span[data.file[k]] = max(span[data.file[k]], float(c.t[-1]))
    rows: dict[str, list] = {k: [] for k in ("e", "axis", "unit", "inv_m", "t_in", "d1", "d2", "s")}
    cap_d1 = np.zeros((len(TAU_DRIFT_S), P))
    cap_d2 = np.zeros(P)
    cap_s = np.zeros((len(TAU_SETTLE_S), P))
    diff_var = np.zeros((P, 3))
    step_units = np.zeros(P)
    means = np.array([c.x.mean(axis=0) / c.per_g for c in caps])
    step = np.zeros((P, 3))
    for k in range(1, P):
        if data.file[k] == data.file[k - 1]:
            step[k] = means[k] - means[k - 1]
    nrm = np.linalg.norm(step, axis=1, keepdims=True)
    step_unit = np.where(nrm > 0, step / np.where(nrm > 0, nrm, 1.0), 0.0)
    for k, c in enumerate(caps):
        x = c.x / c.per_g
        t = np.asarray(c.t, float)
        T = max(span[data.file[k]], 1e-9)
        h1 = 1.0 - np.exp(-t[None, :] / TAU_DRIFT_S[:, None])  # (Gw, n)
        h2 = t / T
        hs = np.exp(-(t[None, :] - t[0]) / TAU_SETTLE_S[:, None])  # (Gs, n)
        cap_d1[:, k], cap_d2[k], cap_s[:, k] = h1.mean(1), h2.mean(), hs.mean(1)
        diff_var[k] = 0.5 * np.var(np.diff(x, axis=0), axis=0, ddof=1) if len(x) > 2 else np.nan
        step_units[k] = value_step(c.x)
        n = len(x)
        B = min(8, n // 12)
        if B < 2:
            continue
        xm = x.mean(axis=0)
        for idx in np.array_split(np.arange(n), B):
            m = len(idx)
            for a in range(3):
                rows["e"].append(x[idx, a].mean() - xm[a])
                rows["axis"].append(a)
                rows["unit"].append(k)
                rows["inv_m"].append(1.0 / m - 1.0 / n)
                rows["t_in"].append(float(t[idx].mean() - t[0]))
                rows["d1"].append(h1[:, idx].mean(1) - cap_d1[:, k])
                rows["d2"].append(h2[idx].mean() - cap_d2[k])
                rows["s"].append(hs[:, idx].mean(1) - cap_s[:, k])
    if not rows["e"]:
        return None
    return TimeData(np.array(rows["e"]), np.array(rows["axis"]), np.array(rows["unit"]), np.array(rows["inv_m"]),
                    np.array(rows["t_in"]), np.array(rows["d1"]).T, np.array(rows["d2"]), np.array(rows["s"]).T,
                    step_unit, cap_d1, cap_d2, cap_s, diff_var, step_units,
                    np.array([c.per_g for c in caps], float))


# -- static design ---------------------------------------------------------------------------

def static_design(E, g, ref, dT, drift_h, norm: bool, n_temps: int, g0=None):
    """Design of the static view for effects E.

    g: (..., P, 3) readings; ref: (P, 3) or None; dT: (P,) or None; drift_h: (..., P, 2) or None;
    g0: (3,) the zero-g reading: a sensor's nonlinearity acts on its response to force, G - g0
    (reading = S a + c (S a)^3 + b), so the cubic and square columns are centred there.
    Returns A (..., P, 3, p), b (..., P, 3), d (p,) norm-shift flags, labels (p,) of (effect, detail).
    """
    lead = g.shape[:-2]
    if drift_h is not None:
        lead = np.broadcast_shapes(lead, drift_h.shape[:-2])
    g = np.broadcast_to(g, lead + g.shape[-2:])
    P = g.shape[-2]
    cols: list[np.ndarray] = []
    labels: list[tuple[str, str]] = []
    d: list[float] = []
    b = np.zeros(lead + (P, 3))

    def add(effect, detail, per_channel: dict[int, np.ndarray], shift: float = 0.0):
        col = np.zeros(lead + (P, 3))
        for c, val in per_channel.items():
            col[..., c] = val
        cols.append(col)
        labels.append((effect, detail))
        d.append(shift)

    ax = "xyz"
    if "cross_axis" in E:
        if norm:
            for i, j in _SYM:
                add("cross_axis" if i != j else "gain", f"W_{ax[i]}{ax[j]}",
                    {i: g[..., j]} if i == j else {i: g[..., j], j: g[..., i]})
        else:
            for i in range(3):
                for j in range(3):
                    add("cross_axis" if i != j else "gain", f"W_{ax[i]}{ax[j]}", {i: g[..., j]})
    elif "gain" in E:
        for c in range(3):
            add("gain", f"W_{ax[c]}{ax[c]}", {c: g[..., c]})
    else:
        b = b + g  # W = I: the nominal sensitivity is taken as exact
    if "offset" in E:
        for c in range(3):
            add("offset", f"V_{ax[c]}", {c: 1.0})
    z0 = np.zeros(3) if g0 is None else np.asarray(g0, float)
    if "cubic" in E:
        for c in range(3):
            add("cubic", f"Gamma_{ax[c]}", {c: (g[..., c] - z0[c]) ** 3})
    if "quadratic" in E:
        for c in range(3):
            add("quadratic", f"Q_{ax[c]}", {c: (g[..., c] - z0[c]) ** 2})
    if "temperature" in E and dT is not None:
        x = dT / T_SCALE_C
        for c in range(3):
            add("temperature", f"gain_{ax[c]}_per_25C", {c: x * g[..., c]})
            add("temperature", f"offset_{ax[c]}_per_25C", {c: x})
            if n_temps >= 3:
                add("temperature", f"gain_{ax[c]}_per_25C2", {c: x**2 * g[..., c]})
                add("temperature", f"offset_{ax[c]}_per_25C2", {c: x**2})
    if "drift" in E and drift_h is not None:
        for c in range(3):
            add("drift", f"warmup_{ax[c]}", {c: -drift_h[..., 0]})
            add("drift", f"trend_{ax[c]}", {c: -drift_h[..., 1]})
    if "gravity" in E:
        if norm:
            add("gravity", "delta", {}, shift=1.0)
        else:
            add("gravity", "delta", {c: -ref[:, c] for c in range(3)})
    A = np.stack(cols, axis=-1) if cols else np.zeros(lead + (P, 3, 0))
    return A, b, np.array(d), labels


def _pinv(G: np.ndarray) -> np.ndarray:
    return np.linalg.pinv(G, rcond=1e-12, hermitian=True)


def _wls(A, y, w):
    """Weighted least squares for a batch: A (N, R, p), y (N, R), w (N, R) -> theta (N, p), C (N, p, p)."""
    Aw = A * w[..., None]
    C = _pinv(A.swapaxes(-1, -2) @ Aw)
    theta = (C @ (Aw.swapaxes(-1, -2) @ y[..., None]))[..., 0]
    return theta, C


def _norm_resid(A, b, d, gamma, theta):
    u = np.einsum("npcq,nq->npc", A, theta) + b
    nrm = np.linalg.norm(u, axis=-1)
    r = nrm - gamma - (theta @ d)[:, None]
    uh = u / np.maximum(nrm, 1e-300)[..., None]
    J = np.einsum("npc,npcq->npq", uh, A) - d
    return r, J, uh


def _lm_norm(A, b, d, gamma, w, theta0, iters: int = 40):
    """Levenberg-Marquardt on r = |A theta + b| - gamma - d theta, weights w (N, P); batch N."""
    theta = np.array(theta0, float)
    N, p = theta.shape
    lam = np.full(N, 1e-3)
    r, J, _ = _norm_resid(A, b, d, gamma, theta)
    cost = np.sum(w * r**2, axis=1)
    for _ in range(iters):
        JtJ = np.einsum("npq,np,npr->nqr", J, w, J)
        grad = np.einsum("npq,np->nq", J, w * r)
        dg = np.maximum(np.einsum("nqq->nq", JtJ), 1e-12)
        M = JtJ + (lam[:, None] * dg)[..., None] * np.eye(p)
        step = -np.linalg.solve(M, grad[..., None])[..., 0]
        tn = theta + step
        rn, Jn, _ = _norm_resid(A, b, d, gamma, tn)
        cn = np.sum(w * rn**2, axis=1)
        ok = np.isfinite(cn) & (cn <= cost)
        theta[ok], r[ok], J[ok] = tn[ok], rn[ok], Jn[ok]
        small = ok & (cost - cn <= 1e-12 * np.maximum(cost, 1e-300))
        cost[ok] = cn[ok]
        lam = np.where(ok, np.maximum(lam / 10, 1e-12), lam * 10)
        if np.all(small | (lam > 1e10)):
            break
    C = _pinv(np.einsum("npq,np,npr->nqr", J, w, J))
    return theta, C


def _norm_start(g: np.ndarray, labels, gamma: float) -> np.ndarray:
    """Start of the norm fit: a sphere centred at the mid-range, radius the median norm."""
    c = 0.5 * (g.max(axis=0) + g.min(axis=0))
    s = float(np.median(np.linalg.norm(g - c, axis=1))) / gamma
    th = np.zeros(len(labels))
    for k, (eff, det) in enumerate(labels):
        if det.startswith("W_") and det[2] == det[3]:
            th[k] = 1.0 / s
        elif det.startswith("V_"):
            th[k] = -c["xyz".index(det[2])] / s
    return th


def design_rank_ok(E, data: GapData, norm: bool) -> tuple[bool, float]:
    """Whether the static terms of E are identifiable on ideal readings (g = ref, or unit readings).

    Judged on ideal data, like designs.predict_stderr, so that noise never makes a
    degenerate term look identifiable.  Returns (ok, column-scaled condition number).
    """
    ideal = data.ref if not norm else data.g / np.linalg.norm(data.g, axis=1, keepdims=True)
    dT = None if data.temp_c is None else data.temp_c - np.mean(data.temp_c)
    td = time_data(data) if "drift" in E else None
    dh = None if td is None else np.stack([td.cap_drift1[len(TAU_DRIFT_S) // 2], td.cap_drift2], axis=-1)
    A, b, d, labels = static_design(E, ideal, data.ref, dT, dh, norm, data.n_temps)
    if not labels:
        return True, 1.0
    if norm:  # at the ideal solution W = I, everything else 0
        th = np.array([1.0 if det.startswith("W_") and det[2] == det[3] else 0.0 for _, det in labels])
        _, J, _ = _norm_resid(A[None], b[None], d, 1.0, th[None])
        M = J[0]
    else:
        M = A.reshape(-1, A.shape[-1])
    sc = np.linalg.norm(M, axis=0)
    if np.any(sc == 0):
        return False, np.inf
    s = np.linalg.svd(M / sc, compute_uv=False)
    cond = float(s[0] / max(s[-1], 1e-300))
    return cond < 1e6, cond


# -- evaluation ------------------------------------------------------------------------------

@dataclass
class Evaluation:
    """Held-out residuals and variances of one model (see module doc)."""

    added: tuple[str, ...]
    n_params: int
    r_static: np.ndarray | None  # (P, m) held-out residuals (m = 3 with references, 1 norm-only), g
    v_static: np.ndarray | None  # (P, m) their predicted variance (floor + fit), g^2
    floor_static: np.ndarray | None  # (P, m) floor alone
    r_time: np.ndarray | None  # (R,) held-out block residuals, g
    v_time: np.ndarray | None
    nll_unit: np.ndarray  # (P, 3) held-out negative log predictive density per pose and axis
    params: dict  # whole-data fit: label -> value
    fitted_static: np.ndarray | None = None  # (P, m) in-sample residuals of the whole-data fit
    r_spread: np.ndarray | None = None  # (P, 3) within-pose variance minus predicted, g^2 (scored, not in gap)
    v_spread: np.ndarray | None = None
    floor_time: np.ndarray | None = None  # (R,) the floor alone of the time view's rows
    pv_static: np.ndarray | None = None  # (P, m) the fit's own prediction variance of the held-out residuals

    def _rows(self):
        r = [x.ravel() for x in (self.r_static, self.r_time) if x is not None]
        v = [x.ravel() for x in (self.v_static, self.v_time) if x is not None]
        return np.concatenate(r), np.concatenate(v)

    @property
    def gap(self) -> float:
        """Held-out residual RMS over the floor's RMS, the floor fixed before any candidate (1.0: at the floor).

        Only the residuals move it: the floor is the same for every model.  With raw captures
        both views count alike: the RMS of the static and time views' ratios.
        """
        gaps = [g for g in (self.floor_gap("static"), self.floor_gap("time")) if g is not None]
        return float(np.sqrt(np.mean(np.square(gaps))))

    def floor_gap(self, view: str) -> float | None:
        r, f = {"static": (self.r_static, self.floor_static), "time": (self.r_time, self.floor_time)}[view]
        return None if r is None else float(np.sqrt(np.sum(r**2) / np.sum(f)))

    def view_gap(self, view: str) -> float | None:
        r, v = {"static": (self.r_static, self.v_static), "time": (self.r_time, self.v_time),
                "spread": (self.r_spread, self.v_spread)}[view]
        return None if r is None else float(np.sqrt(np.sum(r**2) / np.sum(v)))

    @property
    def rms_g(self) -> float:
        r, _ = self._rows()
        return float(np.sqrt(np.mean(r**2)))

    @property
    def expected_rms_g(self) -> float:
        _, v = self._rows()
        return float(np.sqrt(np.mean(v)))

    @property
    def score(self) -> float:
        return float(np.mean(np.sum(self.nll_unit, axis=1)))


def _nll(r, v):
    return 0.5 * (np.log(2 * np.pi * v) + r**2 / v)


def _heldout(x: np.ndarray, fold: np.ndarray) -> np.ndarray:
    """Pick each pose's entry from its own fold: x (F, P, ...) -> (P, ...)."""
    return x[fold, np.arange(x.shape[1])]


def evaluate(data: GapData, floor: Floor, baseline: tuple[str, ...], added: tuple[str, ...] = (),
             td: TimeData | None = None, static_ok: bool = True) -> Evaluation:
    """Held-out evaluation of the model ``baseline + added`` (module doc).

    ``baseline``: the configuration's deterministic effects (fitted); ``added``: candidates.
    Fold K (the last) is the whole-data fit whose parameters are reported.
    """
    E = set(baseline) | set(added)
    P = data.P
    fold = data.folds()
    K = int(fold.max()) + 1
    F = K + 1
    train = np.ones((F, P), bool)
    train[:K] = fold[None, :] != np.arange(K)[:, None]
    params: dict = {}

    # the variance model, per fold
    sigma = np.broadcast_to(floor.sigma_g, (F, 3)).copy()
    q = np.full(F, floor.q_g)
    if "quantization" in added and td is not None:
        q = np.array([td.lsb_g(train[f]) for f in range(F)])
        params["lsb_g"] = float(q[-1])
    if "noise" in added:
        if td is not None:
            w2 = np.array([np.nanmean(td.diff_var[train[f]], axis=0) for f in range(F)])
        else:
            nn = data.n[:, None] - 1.0
            w2 = np.array([np.sum(nn[train[f]] * data.std_g[train[f]] ** 2, 0) / np.sum(nn[train[f]]) for f in range(F)])
        sigma = sigma_from_within(w2, q[:, None])
        params["sigma_g"] = sigma[-1].tolist()

    # spread view: each pose's within-pose variance against the per-sample variance predicted
    # (sample variance: var 2 s^4/(n-1); half the mean squared first difference: 3 s^4/(n-1))
    nll = np.zeros((P, 3))  # test units: (pose, axis); a norm residual goes to the axis nearest gravity
    r_sp = v_sp = None
    w2_obs, c_var = (td.diff_var, 3.0) if td is not None else (data.std_g**2 if data.std_g is not None else None, 2.0)
    if w2_obs is not None:
        pred = np.broadcast_to(random_var(sigma[:, None, :], q[:, None, None]), (F, P, 3))
        vs = c_var * pred**2 / np.maximum(data.n[None, :, None] - 1.0, 1.0) \
            + np.broadcast_to(within_spread(sigma[:, None, :], q[:, None, None]), (F, P, 3))
        ok = np.isfinite(w2_obs)
        r_sp = _heldout(np.where(ok, w2_obs - pred, 0.0), fold)
        v_sp = _heldout(vs, fold)
        nll += np.where(ok, _nll(r_sp, v_sp), 0.0)

    # time view.  Drift: shared terms (held out by capture).  Settling: tau shared, and the
    # transient's amplitude at the start of each capture a random effect a ~ N(0, psi^2) per
    # axis -- auto-segmentation trims every capture's transient by a different amount, so the
    # amplitude is a property of the capture, not of the board.  tau and psi^2 are fitted on
    # training captures by maximum marginal likelihood; a held-out capture is scored by its
    # marginal density N(e; 0, V + psi^2 f f^T) (proper, comparable with the baseline's N(e; 0, V)),
    # and its amplitude estimated (BLUP) to extrapolate the settled mean for the static view.
    r_time = v_time = fl_time = None
    corr = np.zeros((F, P, 3))
    extra = np.zeros((F, P, 3))  # variance the settled-mean extrapolation adds to a pose mean
    n_time = 0
    if td is not None:
        R = len(td.e)
        rows = np.arange(R)
        fr = fold[td.unit]
        v_row = random_var(sigma[:, td.axis], q[:, None]) * td.inv_m  # (F, R)
        wtr = train[:, td.unit] / v_row
        gkey = td.unit * 3 + td.axis
        n_time = (6 if "drift" in E else 0) + (2 if "settling" in E else 0)
        y = np.broadcast_to(td.e, (F, R)).copy()  # data minus the fitted drift
        pv_d = np.zeros((F, R))  # drift's prediction variance
        settle_fit = np.zeros((F, R))
        post_rows = np.zeros((F, R))
        g_all = None
        for _ in range(2 if {"drift", "settling"} <= E else 1):
            if "drift" in E:
                target = td.e[None] - settle_fit
                best_cost = np.full(F, np.inf)
                for a in range(len(TAU_DRIFT_S)):
                    D = np.zeros((R, 6))
                    for c in range(3):
                        on = td.axis == c
                        D[on, 2 * c], D[on, 2 * c + 1] = td.drift1[a][on], td.drift2[on]
                    th, C = _wls(np.broadcast_to(D, (F, R, 6)), target, wtr)
                    cost = np.sum(wtr * (target - th @ D.T) ** 2, axis=1)
                    b = cost < best_cost
                    best_cost[b] = cost[b]
                    y[b] = td.e[None] - th[b] @ D.T
                    pv_d[b] = np.einsum("rp,fpq,rq->fr", D, C[b], D)
                    if b[-1]:
                        params["drift_tau_s_time"] = float(TAU_DRIFT_S[a])
                        params.update({f"drift_time:{k}_{ax}": float(v) for (ax, k), v in
                                       zip([(ax, k) for ax in "xyz" for k in ("warmup", "trend")], th[-1])})
            if "settling" in E:
                wv = 1.0 / v_row  # (F, R)
                Sff = np.stack([np.stack([np.bincount(gkey, wv[fo] * f * f, minlength=3 * P) for fo in range(F)])
                                for f in td.settle])  # (Gs, F, G)
                Sfe = np.stack([np.stack([np.bincount(gkey, wv[fo] * f * y[fo], minlength=3 * P) for fo in range(F)])
                                for f in td.settle])
                psi2 = _PSI2_GRID[:, None, None, None]
                gain = 0.5 * (psi2 * Sfe**2 / (1 + psi2 * Sff) - np.log1p(psi2 * Sff))  # (Q, Gs, F, G)
                ll = np.sum(gain * np.repeat(train, 3, axis=1), axis=-1)  # (Q, Gs, F): training captures only
                qi, si = np.unravel_index(ll.reshape(-1, F).argmax(axis=0), ll.shape[:2])
                fi = np.arange(F)
                p2, sff, sfe = _PSI2_GRID[qi][:, None], Sff[si, fi], Sfe[si, fi]  # (F, 1), (F, G)
                g_all = gain[qi, si, fi]  # (F, G): log marginal density gain of every capture-axis
                post = np.where(p2 > 0, 1.0 / (1.0 / np.where(p2 > 0, p2, 1.0) + sff), 0.0)  # Var(a | e), g^2
                a_hat = post * sfe  # BLUP amplitude at the capture's start, g
                f_rows = td.settle[si]  # (F, R)
                settle_fit = a_hat[:, gkey] * f_rows
                post_rows = post[:, gkey] * f_rows**2
                cap = td.cap_settle[si]  # (F, P)
                corr = a_hat.reshape(F, P, 3) * cap[:, :, None]
                extra = post.reshape(F, P, 3) * cap[:, :, None] ** 2
                params["settling_tau_s"] = float(TAU_SETTLE_S[si[-1]])
                params["settling_amplitude_mg_rms"] = float(1e3 * np.sqrt(p2[-1, 0]))
                params["_settling_a_g"] = _heldout(a_hat.reshape(F, P, 3), fold)  # each capture's, held out
        r_time = (y - settle_fit)[fr, rows]
        fl_time = v_row[fr, rows]
        v_time = (v_row + pv_d - post_rows)[fr, rows]  # Var(e - f a_hat) = V - f^2 Var(a | e)
        np.add.at(nll, (td.unit, td.axis), _nll(y[fr, rows], (v_row + pv_d)[fr, rows]))
        if g_all is not None:
            nll -= g_all[np.repeat(fold, 3), np.arange(3 * P)].reshape(P, 3)

    # static view
    r_s = v_s = fl_s = fit_s = pv_s = None
    n_static = 0
    if static_ok:
        norm = data.norm_only
        g = data.g[None] - corr  # (F, P, 3): settling's transient mean removed
        dT = None if data.temp_c is None else data.temp_c - np.mean(data.temp_c)
        use_drift = "drift" in E and td is not None
        grid = range(len(TAU_DRIFT_S)) if use_drift else [None]
        s2 = np.full(F, floor.scatter_rad**2)
        floor0 = np.broadcast_to(mean_var(sigma[:, None, :], q[:, None, None], data.n[None, :, None]), (F, P, 3))
        base_v = floor0 + extra  # (F, P, 3)
        shape = None if norm else 1.0 - (data.ref / np.linalg.norm(data.ref, axis=1, keepdims=True)) ** 2
        if norm:
            uh0 = data.g / np.linalg.norm(data.g, axis=1, keepdims=True)
            floor0 = np.sum(uh0**2 * floor0, axis=-1)[..., None]
        else:
            floor0 = floor0 + floor.scatter_rad**2 * shape[None]
        n_iter = 3 if "pose_error" in added and not norm else 1
        for it in range(n_iter):
            outs = []
            for a in grid:
                dh = None if a is None else np.stack([td.cap_drift1[a], td.cap_drift2], axis=-1)
                A, b, d, labels = static_design(E, g, data.ref, dT, dh, norm, data.n_temps, data.zero_g)
                p = A.shape[-1]
                if norm:
                    uh = data.g / np.linalg.norm(data.g, axis=1, keepdims=True)
                    v0 = np.sum(uh**2 * base_v, axis=-1)  # (F, P)
                    w = train / v0
                    th0 = np.broadcast_to(_norm_start(data.g, labels, floor.gamma), (F, p))
                    th, C = _lm_norm(A, b, d, floor.gamma, w, th0)
                    r, J, _ = _norm_resid(A, b, d, floor.gamma, th)
                    pv = np.einsum("fpq,fqr,fpr->fp", J, C, J)
                    r, v0, pv = r[..., None], v0[..., None], pv[..., None]
                    lev = w[..., None] * pv
                else:
                    v0 = base_v + s2[:, None, None] * shape[None]
                    y = (floor.gamma * data.ref)[None] - b  # (F, P, 3)
                    Af = A.reshape(F, P * 3, p)
                    wf = (train[:, :, None] / v0).reshape(F, P * 3)
                    th, C = _wls(Af, y.reshape(F, P * 3), wf)
                    r = y - np.einsum("fpcq,fq->fpc", A, th)
                    pv = np.einsum("fpcq,fqr,fpcr->fpc", A, C, A)
                    lev = (train[:, :, None] / v0) * pv
                cost = np.sum(train[:, :, None] * r**2 / v0, axis=(1, 2))
                outs.append((cost, r, v0, pv, lev, th, labels, p))
            costs = np.stack([o[0] for o in outs])
            best = np.argmin(costs, axis=0)
            pick = lambda k: np.stack([outs[best[f]][k][f] for f in range(F)])  # noqa: E731
            r, v0, pv, lev, th = pick(1), pick(2), pick(3), pick(4), pick(5)
            labels, n_static = outs[best[-1]][6], outs[best[-1]][7]
            if use_drift:
                params["drift_tau_s"] = float(TAU_DRIFT_S[grid[best[-1]]])
            if it < n_iter - 1:
                # maximum likelihood s^2 per fold on leverage-corrected training residuals
                rc2 = r**2 / np.clip(1.0 - lev, 0.05, 1.0)
                vb = base_v[:, None] + _S2_GRID[None, :, None, None] * shape[None, None]  # (F, S, P, 3)
                ll = -0.5 * np.sum(train[:, None, :, None] * (np.log(vb) + rc2[:, None] / vb), axis=(2, 3))
                s2 = _S2_GRID[np.argmax(ll, axis=1)]
        fit_s = r[-1]
        params.update({f"{e}:{det}": float(v) for (e, det), v in zip(labels, th[-1])})
        if "pose_error" in added and not norm:
            params["scatter_deg"] = float(np.degrees(np.sqrt(s2[-1])))
        r_s = _heldout(r, fold)
        fl_s = _heldout(floor0, fold)
        v_s = _heldout(v0 + pv, fold)
        pv_s = _heldout(pv, fold)
        if norm:
            np.add.at(nll, (np.arange(P), np.argmax(np.abs(data.g), axis=1)), _nll(r_s, v_s)[:, 0])
        else:
            nll += _nll(r_s, v_s)
    n_var = {"pose_error": 1}  # noise and quantization are measured within poses, not fitted to residuals
    n_params = n_static + n_time + sum(n_var.get(a, 0) for a in added)
    return Evaluation(tuple(added), n_params, r_s, v_s, fl_s, r_time, v_time, nll, params, fit_s, r_sp, v_sp,
                      fl_time, pv_s)
