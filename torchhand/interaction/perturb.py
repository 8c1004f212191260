"""Perturbation check of the joint compliance (Kry & Pai 2006 §4.2, Table 2), simulated by MuJoCo.

The paper's subject pressed a spring-loaded platform; pulling a pin unlatched it, and the platform pushed the finger
up. The fingertip elevation z(t) (motion capture, 500 Hz, velocities and accelerations by numerical
differentiation) and the vertical force f(t) measured under the platform were fitted on a short window starting at
the release (25 ms exploring, 20 ms scratching) with the second-order model

    f(t) = m z''(t) + b z'(t) + k z(t) + f0,    f0: the rest force at the time of perturbation,

and k was compared with kG, the vertical component of the effective endpoint stiffness from G = J C J^T at the
posture of the perturbation (Eq. 5; design note decision 10: kG = 1 / (e_z^T G e_z), lateral motion free).

Here the finger is the planar finger of :mod:`torchhand.interaction.mujoco_truth` (same links and hinges; wrist,
MP, PIP, DIP), now dynamic: MuJoCo joint springs of stiffness 1 / c_j (Table 1, the settings' task), joint damping
``damping_time / c_j`` (stiffness-proportional, so the tip's damping is about damping_time x its stiffness), link
masses of 5-15 g, gravity off (it only adds a constant to f0). The reference posture is set so that the fingertip
presses the platform with ``press_force`` newtons at the chosen posture: theta_r = theta - C J^T f. The platform is
a box on a vertical slide joint with a pre-loaded spring (``platform_preload`` newtons more than the press force, so
that it lifts the finger), held by a joint equality (the latch) while the finger settles; at the release the
equality is switched off and the platform pushes the finger up until it reaches its stop ``platform_travel`` above.
The platform is frictionless by default (``friction = 0``): the tip then moves freely sideways, as kG assumes; with
friction the tip is held sideways and the comparison is (G_xz^-1)_zz, which is reported as well.

Recorded (every simulation step, sampled at ``rate`` Hz for the fit): z, the world height of the link-fixed
fingertip contact point (where the distal link touched the platform at the release) relative to its height at the
release, and f, the vertical contact force of the platform on the finger (MuJoCo ``mj_contactForce``). The fit
differentiates z numerically (five-point central differences, :func:`derivatives`) and solves the least-squares
problem for (m, b, k) on the window [release, release + window] with f0 the measured rest force (the mean force over
:data:`REST_AVERAGE` before the release: the paper's definition). ``fit_free_f0`` repeats the fit with f0 as a fourth
unknown, which these data barely determine: after the release the tip rises at an almost constant speed, so b z' and
f0 are nearly collinear on the window, and that fit trades k for f0 (k about half of kG or less).

Measured with the defaults (docs/kry_pai_reproduction.md): k within 8.1 % (exploring) and 6.4 % (scratching) of kG
at 500 Hz (the paper: 8.2 %, 11.3 %), b > 0, m 42-51 % above the endpoint mass; at 10 kHz, where the numerical
derivatives no longer matter, k is 13.5 % and 10.3 % below kG and m 24-26 % above the endpoint mass. At a strongly
curled posture the single-degree-of-freedom fit fails (k 25-51 % below kG).

References reported next to the fit: kG = 1 / G_zz and (G_xz^-1)_zz from torchhand's own point Jacobian of the
planar finger (``effective_compliance`` of :mod:`torchhand.kernels.contact_lcp`, as the quasi-static step uses it),
and the effective endpoint mass 1 / (e_z^T J M^-1 J^T e_z) with MuJoCo's mass matrix (``mj_fullM``) and point
Jacobian (``mj_jac``).

MuJoCo is a test dependency (``pip install torchhand[test]``); this module imports it lazily.

Layout: the fit is :mod:`._second_order_fit`, the endpoint references :mod:`._endpoint`; this module holds the
trial's settings, model and simulation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputValueError
from ._endpoint import EndpointReference, endpoint_compliance, endpoint_reference
from ._second_order_fit import FitStatus, SecondOrderFit, derivatives, fit_second_order
from .compliance import TABLE1
from .mujoco_truth import _LENGTHS, _RADII, JOINTS, LINKS, ROOT_HEIGHT, _mujoco, planar_finger_mjcf

__all__ = ["PAPER_TABLE2", "PerturbSettings", "SecondOrderFit", "FitStatus", "EndpointReference", "PerturbResult",
           "perturbation_mjcf", "derivatives", "fit_second_order", "endpoint_compliance", "endpoint_reference",
           "simulate_perturbation"]

PAPER_TABLE2 = {
    "exploring": {"f": 0.677, "m": 0.017, "b": 2.04, "k": 89.16, "kG": 81.86, "window": 0.025},
    "scratching": {"f": 1.345, "m": 0.018, "b": 3.86, "k": 257.04, "kG": 285.96, "window": 0.020},
}
"""Kry & Pai (2006) Table 2: rest force f (N), m (kg), b (N s/m), k (N/m), kG (N/m); the fit window (s, §4.2)."""

TIMESTEP = 5e-5  # s
PLATFORM_HALF = (0.03, 0.03, 0.005)  # m, the platform box's half sizes
REST_AVERAGE = 0.005  # s: the rest force is the mean force over this long before the release


@dataclass(frozen=True)
class PerturbSettings:
    """Settings of a simulated perturbation trial (module docstring).

    task:             "exploring" or "scratching": the Table 1 column of the joint compliance (scratching: the
                      paper's upper bounds for PIP and DIP), and the paper's press force and window by default
    posture:          joint angles at the release (wrist, MP, PIP, DIP), (4,), radians (positive flexes down)
    press_force:      rest force of the fingertip on the platform, newtons (None: Table 2's f of the task)
    window:           fit window after the release, seconds (None: 25 ms exploring, 20 ms scratching)
    rate:             sampling rate of z and f for the fit, Hz (the paper: 500)
    link_mass:        masses of the palm, proximal, middle and distal links, (4,), kg
    damping_time:     joint damping = damping_time / c_j, seconds
    platform_mass:    kg
    platform_preload: upward spring force of the latched platform beyond the press force, newtons
    platform_stiffness: the platform spring's stiffness, N/m
    platform_travel:  height of the platform's upper stop above its latched position, metres
    friction:         fingertip-platform friction coefficient (0: frictionless, lateral motion free)
    settle_time:      seconds with the platform latched before the release
    after_time:       seconds simulated after the release (>= window)
    compliance:       joint compliances (4,), rad/(N m), or None for Table 1 of ``task``
    """

    task: str = "exploring"
    posture: tuple = (0.25, 0.45, 0.55, 0.35)
    press_force: float | None = None
    window: float | None = None
    rate: float = 500.0
    link_mass: tuple = (0.015, 0.010, 0.007, 0.005)
    damping_time: float = 0.02
    platform_mass: float = 0.02
    platform_preload: float = 0.5
    platform_stiffness: float = 50.0
    platform_travel: float = 0.004
    friction: float = 0.0
    settle_time: float = 0.3
    after_time: float = 0.05
    compliance: tuple | None = None

    def __post_init__(self):
        if self.task not in TABLE1:
            raise InputValueError(f"task: expected one of {', '.join(TABLE1)}, got {self.task!r}")
        for name, n in (("posture", 4), ("link_mass", 4)):
            v = getattr(self, name)
            if len(tuple(v)) != n or not all(math.isfinite(float(x)) for x in v):
                raise InputValueError(f"{name}: expected {n} finite values, got {v!r}")
        if not all(float(x) > 0 for x in self.link_mass):
            raise InputValueError(f"link_mass: expected positive masses (kg), got {self.link_mass!r}")
        if self.compliance is not None and (len(tuple(self.compliance)) != 4
                                            or not all(float(x) > 0 for x in self.compliance)):
            raise InputValueError(f"compliance: expected 4 positive values, rad/(N m), got {self.compliance!r}")
        for name in ("rate", "damping_time", "platform_mass", "platform_preload", "platform_stiffness",
                     "platform_travel", "settle_time", "after_time"):
            if not getattr(self, name) > 0:
                raise InputValueError(f"{name}: expected > 0, got {getattr(self, name)}")
        if not self.rate * TIMESTEP <= 1:
            raise InputValueError(f"rate: expected <= {1 / TIMESTEP:g} Hz, got {self.rate}")
        if self.press_force is not None and not self.press_force > 0:
            raise InputValueError(f"press_force: expected > 0 N, got {self.press_force}")
        if self.window is not None and not 0 < self.window <= self.after_time:
            raise InputValueError(f"window: expected in (0, after_time = {self.after_time}] s, got {self.window}")
        if not self.friction >= 0:
            raise InputValueError(f"friction: expected >= 0, got {self.friction}")

    @property
    def joint_compliance(self) -> np.ndarray:
        """(4,) rad/(N m): ``compliance`` or Table 1 of the task."""
        if self.compliance is not None:
            return np.asarray(self.compliance, dtype=np.float64)
        t = TABLE1[self.task]
        return np.array([t[j] for j in JOINTS])

    @property
    def force(self) -> float:
        """The press force, newtons."""
        return float(self.press_force if self.press_force is not None else PAPER_TABLE2[self.task]["f"])

    @property
    def fit_window(self) -> float:
        """The fit window, seconds."""
        return float(self.window if self.window is not None else PAPER_TABLE2[self.task]["window"])


@dataclass(frozen=True, eq=False)
class PerturbResult:
    """A simulated perturbation trial.

    settings: :class:`PerturbSettings`; t: sample times relative to the release, (S,), s; z: fingertip height
    relative to the release, (S,), m; f: vertical force of the platform on the finger, (S,), N (sampled at
    ``settings.rate``); release: index of the release sample in t; f_rest: the measured force just before the
    release, N; theta: joint angles at the release, (4,), rad; point_local: the fingertip contact point in the distal
    link's frame, (3,), m; fit: :class:`SecondOrderFit` with f0 = f_rest (the paper's rest force); fit_free_f0: the
    same with f0 fitted as a fourth unknown; reference: :class:`EndpointReference` at the release posture with the
    simulated compliance; lost_contact: the fingertip left the platform inside the window; t_sim, z_sim, f_sim:
    the same signals at every simulation step, (S',); mjcf: the simulated model
    """

    settings: PerturbSettings
    t: np.ndarray
    z: np.ndarray
    f: np.ndarray
    release: int
    f_rest: float
    theta: np.ndarray
    point_local: np.ndarray
    fit: SecondOrderFit
    fit_free_f0: SecondOrderFit
    reference: EndpointReference
    lost_contact: bool
    t_sim: np.ndarray
    z_sim: np.ndarray
    f_sim: np.ndarray
    mjcf: str

    @property
    def k_error(self) -> float:
        """(k - kG) / kG."""
        return self.fit.k / self.reference.kG - 1.0

    @property
    def m_error(self) -> float:
        """(m - m_eff) / m_eff."""
        return self.fit.m / self.reference.mass - 1.0


def perturbation_mjcf(settings: PerturbSettings, theta_r, platform_z: float, platform_x: float = 0.12) -> str:
    """MJCF of the dynamic planar finger over the spring-loaded platform.

    theta_r: joint spring references (4,), radians; platform_z: height of the platform's top when latched, metres;
    platform_x: the platform's centre along the finger, metres (world x; the fingertip's contact point)
    """
    c = settings.joint_compliance
    th = np.asarray(theta_r, dtype=np.float64)
    body = ""
    for j in reversed(range(4)):
        m = float(settings.link_mass[j])
        L, r = _LENGTHS[j], _RADII[j]
        inertia = m * (L * L / 12 + r * r / 4)
        pos = "0 0 0" if j == 0 else f"{_LENGTHS[j - 1]:.17g} 0 0"
        x0, x1 = (0.01, L - 0.01) if j < 3 else (0.0, L - r)
        body = (f'<body name="{LINKS[j]}" pos="{pos}">'
                f'<joint name="{JOINTS[j]}" type="hinge" axis="0 1 0" stiffness="{1.0 / c[j]:.17g}" '
                f'springref="{th[j]:.17g}" damping="{settings.damping_time / c[j]:.17g}"/>'
                f'<inertial pos="{L / 2:.17g} 0 0" mass="{m:.17g}" diaginertia="{m * r * r / 2:.17g} {inertia:.17g} {inertia:.17g}"/>'
                f'<geom name="{LINKS[j]}_geom" type="capsule" fromto="{x0:.17g} 0 0 {x1:.17g} 0 0" size="{r:.17g}" '
                f'contype="1" conaffinity="0"/>{body}</body>')
    hx, hy, hz = PLATFORM_HALF
    pm = settings.platform_mass
    ks = settings.platform_stiffness
    preload = settings.force + settings.platform_preload
    condim = 1 if settings.friction == 0 else 3
    return f"""<mujoco model="planar_finger_perturbation">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{TIMESTEP:.17g}" gravity="0 0 0" integrator="implicitfast" cone="elliptic"/>
  <worldbody>
    <body name="forearm" pos="0 0 {ROOT_HEIGHT:.17g}">
      {body}
    </body>
    <body name="platform" pos="{platform_x:.17g} 0 {platform_z - hz:.17g}">
      <joint name="platform_z" type="slide" axis="0 0 1" stiffness="{ks:.17g}" springref="{preload / ks:.17g}"
             range="-0.05 {settings.platform_travel:.17g}"/>
      <inertial pos="0 0 0" mass="{pm:.17g}" diaginertia="1e-5 1e-5 1e-5"/>
      <geom name="platform_geom" type="box" priority="1" size="{hx:.17g} {hy:.17g} {hz:.17g}" contype="0"
            conaffinity="1" condim="{condim}" friction="{max(settings.friction, 1e-9):.17g} 0.005 0.0001" solref="0.0005 1"
            solimp="0.99 0.999 0.001"/>
    </body>
  </worldbody>
  <equality>
    <joint name="latch" joint1="platform_z" polycoef="0 1 0 0 0" solref="0.0005 1"/>
  </equality>
</mujoco>
"""


def _press_posture(settings: PerturbSettings):
    """The platform top under the posture's fingertip and the spring reference that presses it there.

    returns: (the contact point in the world (3,), m; the same in the distal link's frame (3,); theta_r (4,), rad)
    raises: InputValueError when another link is lower than the fingertip
    """
    mujoco = _mujoco()
    c = settings.joint_compliance
    theta = np.asarray(settings.posture, dtype=np.float64)
    model = mujoco.MjModel.from_xml_string(planar_finger_mjcf(c))
    data = mujoco.MjData(model)
    data.qpos[:] = theta
    mujoco.mj_forward(model, data)
    lows = []                                                        # per link: lowest surface point
    for j, name in enumerate(LINKS):
        b = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)
        R, x = data.xmat[b].reshape(3, 3), data.xpos[b]
        x0, x1 = (0.01, _LENGTHS[j] - 0.01) if j < 3 else (0.0, _LENGTHS[j] - _RADII[j])
        ends = [x + R @ np.array([s, 0.0, 0.0]) for s in (x0, x1)]
        centre = min(ends, key=lambda e: e[2])
        lows.append(centre - np.array([0.0, 0.0, _RADII[j]]))
    if int(np.argmin([p[2] for p in lows])) != 3:
        raise InputValueError(f"posture: {tuple(settings.posture)} does not put the fingertip lowest; flex the "
                              f"distal joints")
    b3 = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, LINKS[3])
    point_local = data.xmat[b3].reshape(3, 3).T @ (lows[3] - data.xpos[b3])
    jac = np.zeros((3, model.nv))
    mujoco.mj_jac(model, data, jac, None, lows[3], b3)
    theta_r = theta - c * (jac.T @ np.array([0.0, 0.0, settings.force]))   # theta - theta_r = C J^T f
    return lows[3], point_local, theta_r


@dataclass(frozen=True, eq=False)
class _Trial:
    """The signals of a simulated trial at every simulation step (S steps, TIMESTEP apart).

    force: vertical force of the platform on the finger, (S,), N; pos, rot: the distal link's world position (S, 3)
    and rotation (S, 3, 3); theta: joint angles at the release, (4,), rad; point_local: the fingertip contact point
    at the release, distal link frame, (3,), m; n_settle: the release step; sub: simulation steps per sample
    """

    force: np.ndarray
    pos: np.ndarray
    rot: np.ndarray
    theta: np.ndarray
    point_local: np.ndarray
    n_settle: int
    sub: int


def _vertical_force(mujoco, m, d, platform_geom: int, distal_geom: int, f6: np.ndarray) -> float:
    """The vertical force of the platform on the distal link, summed over their contacts, newtons."""
    total = 0.0
    for i in range(d.ncon):
        con = d.contact[i]
        if {con.geom1, con.geom2} == {platform_geom, distal_geom}:
            mujoco.mj_contactForce(m, d, i, f6)
            fw = con.frame.reshape(3, 3).T @ f6[:3]          # on geom2, world
            total += fw[2] if con.geom2 == distal_geom else -fw[2]
    return total


def _run_trial(mujoco, m, d, settings: PerturbSettings, theta: np.ndarray, point_local: np.ndarray) -> _Trial:
    """Settle with the platform latched, release it (the equality off) and record every step (module docstring)."""
    platform_geom = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "platform_geom")
    distal_geom = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, f"{LINKS[3]}_geom")
    distal = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, LINKS[3])
    f6 = np.zeros(6)
    n_settle = int(round(settings.settle_time / TIMESTEP))
    n_after = int(round(settings.after_time / TIMESTEP))
    sub = int(round(1.0 / (settings.rate * TIMESTEP)))
    n_settle = max(n_settle // sub, 1) * sub                       # the release falls on a sample
    S = n_settle + n_after + 1
    mujoco.mj_forward(m, d)
    force, pos, rot = np.empty(S), np.empty((S, 3)), np.empty((S, 3, 3))
    theta_rel, p_local = theta, point_local
    for k in range(S):
        if k == n_settle:                                            # the release
            theta_rel = d.qpos[:4].copy()
            for i in range(d.ncon):                                  # the contact point, distal link frame
                con = d.contact[i]
                if {con.geom1, con.geom2} == {platform_geom, distal_geom}:
                    p_local = d.xmat[distal].reshape(3, 3).T @ (con.pos - d.xpos[distal])
                    break
            d.eq_active[0] = 0
            mujoco.mj_forward(m, d)
        force[k] = _vertical_force(mujoco, m, d, platform_geom, distal_geom, f6)
        pos[k], rot[k] = d.xpos[distal], d.xmat[distal].reshape(3, 3)
        if k < S - 1:
            mujoco.mj_step(m, d)
    return _Trial(force, pos, rot, theta_rel, p_local, n_settle, sub)


def simulate_perturbation(settings: PerturbSettings = PerturbSettings()) -> PerturbResult:
    """Simulate one perturbation trial and fit it (module docstring).

    returns: :class:`PerturbResult`
    raises: InputValueError when the posture does not put the fingertip lowest
    """
    mujoco = _mujoco()
    c = settings.joint_compliance
    theta = np.asarray(settings.posture, dtype=np.float64)
    tip, point_local, theta_r = _press_posture(settings)
    xml = perturbation_mjcf(settings, theta_r, float(tip[2]), float(tip[0]))
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    d.qpos[:4] = theta
    d.eq_active[0] = 1
    trial = _run_trial(mujoco, m, d, settings, theta, point_local)
    force, n_settle, sub, p_local = trial.force, trial.n_settle, trial.sub, trial.point_local
    S = force.shape[0]
    z_world = trial.pos[:, 2] + trial.rot[:, 2, :] @ p_local
    t_sim = (np.arange(S) - n_settle) * TIMESTEP
    z_sim = z_world - z_world[n_settle]
    idx = np.arange(0, S, sub)
    t, z, f = t_sim[idx], z_sim[idx], force[idx]
    rest_steps = max(1, int(round(REST_AVERAGE / TIMESTEP)))
    f_rest = float(force[n_settle - rest_steps:n_settle].mean())
    window = settings.fit_window
    fit = fit_second_order(t, z, f, 0.0, window, f0=f_rest)
    fit_free = fit_second_order(t, z, f, 0.0, window)
    ref = endpoint_reference(m, d, trial.theta, p_local, c)
    in_win = (t >= 0) & (t <= window + 1e-12)
    return PerturbResult(settings=settings, t=t, z=z, f=f, release=int(n_settle // sub), f_rest=f_rest,
                         theta=trial.theta, point_local=np.asarray(p_local, dtype=np.float64), fit=fit,
                         fit_free_f0=fit_free, reference=ref, lost_contact=bool((f[in_win] <= 0).any()),
                         t_sim=t_sim, z_sim=z_sim, f_sim=force, mjcf=xml)
