"""Synthetic captures with known compliance, simulated by MuJoCo (independent of the estimator under test).

The hand is a planar finger (design note §5.1): a fixed forearm (the root), and four hinges about y, wrist, MP,
PIP and DIP, with capsule links of 8, 4.5, 2.5 and 2 cm; positive angles flex the finger down towards a fixed box
whose top is the plane z = 0. Each joint is a MuJoCo spring with ``stiffness = 1 / c_j`` (c from Table 1,
"exploring" or "scratching") and damping ``DAMPING_RATIO`` x ``c_j``-scaled critical damping; links are light
(:data:`LINK_MASS` kg), gravity is off, contacts are stiff (``solref`` 0.0005 1, ``solimp`` 0.99 0.999 1 mm),
friction 1 (the tip sticks), elliptic cones; time step :data:`TIMESTEP`. With light links and this damping the
motion is quasi-static: theta - theta_r = C J^T f holds to within about 1 % of the largest deflection in
half of the loaded frames and 2 % in nine tenths (:func:`equilibrium_residual`; larger while the finger
lifts off), which the tests check.

Each press moves the spring reference theta_r (MuJoCo's ``model.qpos_spring``, changed every step) from a random
posture 12-35 mm above the plane along ``theta_a + v t + a t^2 / 2`` (|a| <= ``max_accel``, default 2 rad/s^2; v
scaled so that the fingertip reference approaches at ``approach_speed`` m/s), through contact, keeps pressing for
``press_time`` (130 ms) after the predicted contact (a voluntary change after t_c + 100 ms), then returns to theta_a
with a minimum-jerk profile. Frames are recorded at ``rate`` Hz: joint angles and, per hand link, the sum of its
contact forces on the hand (world, from ``mj_contactForce`` rotated by the contact frame) applied at their force-
weighted mean point (exact for the single capsule-box contact a link makes here), expressed in the link frame.
Gaussian noise of ``noise_angle_deg`` on every angle and ``noise_force`` newtons on every force component (every
sensor, every frame) is drawn from the given NumPy generator.

Lighter links (0.05 g) make the finger bounce off the plane at these speeds (extra, short events), heavier ones
lag more; 0.2 g at 0.05 ms steps is the compromise used here.

MuJoCo is a test dependency (``pip install torchhand[test]``); this module imports it lazily.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputValueError, TorchhandError
from .capture import Capture, save_capture
from .compliance import TABLE1

__all__ = ["TruthSettings", "TruthRun", "planar_finger_mjcf", "simulate_presses", "write_truth_capture",
           "equilibrium_residual", "JOINTS", "LINKS"]

JOINTS = ("wrist", "mp", "pip", "dip")
LINKS = ("palm", "proximal", "middle", "distal")
_LENGTHS = (0.08, 0.045, 0.025, 0.02)  # metres, joint to joint (the distal: joint to tip)
_RADII = (0.010, 0.008, 0.007, 0.006)
LINK_MASS = 2e-4  # kg per link
TIMESTEP = 5e-5  # s
DAMPING_RATIO = 0.7
ROOT_HEIGHT = 0.08  # m: the wrist axis above the plane


@dataclass(frozen=True)
class TruthSettings:
    """Settings of a simulated capture.

    task:            "exploring" or "scratching" (Table 1 column for the joint stiffness)
    presses:         number of presses (contact events)
    rate:            recorded frame rate, Hz
    noise_angle_deg: angle noise standard deviation, degrees
    noise_force:     force noise standard deviation per component, newtons
    approach_speed:  fingertip reference speed towards the plane at the start of a press, m/s
    press_time:      how long the reference keeps pressing after the predicted contact, seconds (> 0.1)
    max_accel:       bound of the reference's angular acceleration per joint, rad/s^2 (uniform in +/- it)
    """

    task: str = "exploring"
    presses: int = 80
    rate: float = 500.0
    noise_angle_deg: float = 0.2
    noise_force: float = 0.01
    approach_speed: float = 0.3
    press_time: float = 0.13
    max_accel: float = 2.0

    def __post_init__(self):
        if self.task not in TABLE1:
            raise InputValueError(f"task: expected one of {', '.join(TABLE1)}, got {self.task!r}")
        if not (isinstance(self.presses, int) and 1 <= self.presses <= 1000):
            raise InputValueError(f"presses: expected an integer in [1, 1000], got {self.presses!r}")
        if not (self.rate > 0 and round(1.0 / (self.rate * TIMESTEP)) >= 1):
            raise InputValueError(f"rate: expected a positive frame rate <= {1 / TIMESTEP:g} Hz, got {self.rate}")
        for name in ("noise_angle_deg", "noise_force"):
            if not getattr(self, name) >= 0:
                raise InputValueError(f"{name}: expected >= 0, got {getattr(self, name)}")
        if not self.max_accel >= 0:
            raise InputValueError(f"max_accel: expected >= 0 rad/s^2, got {self.max_accel}")
        if not self.approach_speed > 0:
            raise InputValueError(f"approach_speed: expected > 0 m/s, got {self.approach_speed}")
        if not self.press_time > 0.1:
            raise InputValueError(f"press_time: expected > 0.1 s (the reflex-free window), got {self.press_time}")

    @property
    def compliance(self) -> np.ndarray:
        """Joint compliances (wrist, MP, PIP, DIP), rad/(N m)."""
        t = TABLE1[self.task]
        return np.array([t["wrist"], t["mp"], t["pip"], t["dip"]])


@dataclass(frozen=True)
class TruthRun:
    """A simulated capture (noisy), its noise-free twin and the reference.

    capture:       noisy :class:`Capture` (``truth_compliance`` set, ``hand`` the MJCF file name)
    clean:         the same without noise
    theta_r:       the spring reference at the frames, (T, D), radians
    contact_time:  predicted contact time of each press, (P,), seconds
    mjcf:          the MJCF text (write it next to the capture under the name in ``capture.hand``)
    """

    capture: Capture
    clean: Capture
    theta_r: np.ndarray
    contact_time: np.ndarray
    mjcf: str


def planar_finger_mjcf(compliance) -> str:
    """MJCF of the planar finger with joint springs ``1 / compliance`` (4,), rad/(N m)."""
    c = np.asarray(compliance, dtype=np.float64)
    if c.shape != (4,) or not (c > 0).all():
        raise InputValueError(f"compliance: expected 4 positive values, rad/(N m), got {c.tolist()}")
    inertia = LINK_MASS * 1e-4  # kg m^2, about (1 cm)^2 m
    # effective inertia about each joint: the links beyond it at their mid points
    mids = np.cumsum((0.0,) + _LENGTHS)[:-1] + np.array(_LENGTHS) / 2
    eff = [sum(LINK_MASS * (mids[i] - np.cumsum((0.0,) + _LENGTHS)[j]) ** 2 + inertia for i in range(j, 4))
           for j in range(4)]
    damping = [2 * DAMPING_RATIO * math.sqrt(eff[j] / c[j]) for j in range(4)]
    body = ""
    for j in reversed(range(4)):
        pos = "0 0 0" if j == 0 else f"{_LENGTHS[j - 1]:.17g} 0 0"
        x0, x1 = (0.01, _LENGTHS[j] - 0.01) if j < 3 else (0.0, _LENGTHS[j] - _RADII[j])
        body = (f'<body name="{LINKS[j]}" pos="{pos}">'
                f'<joint name="{JOINTS[j]}" type="hinge" axis="0 1 0" range="-1.6 1.6" '
                f'stiffness="{1.0 / c[j]:.17g}" damping="{damping[j]:.17g}"/>'
                f'<inertial pos="{_LENGTHS[j] / 2:.17g} 0 0" mass="{LINK_MASS:.17g}" '
                f'diaginertia="{inertia:.17g} {inertia:.17g} {inertia:.17g}"/>'
                f'<geom name="{LINKS[j]}_geom" type="capsule" fromto="{x0:.17g} 0 0 {x1:.17g} 0 0" '
                f'size="{_RADII[j]:.17g}" contype="1" conaffinity="0"/>{body}</body>')
    return f"""<mujoco model="planar_finger">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{TIMESTEP:.17g}" gravity="0 0 0" integrator="implicitfast" cone="elliptic"/>
  <worldbody>
    <geom name="surface" type="box" size="0.3 0.1 0.01" pos="0.1 0 -0.01" contype="0" conaffinity="1"
          friction="1 0.005 0.0001" solref="0.0005 1" solimp="0.99 0.999 0.001"/>
    <body name="forearm" pos="0 0 {ROOT_HEIGHT:.17g}">
      {body}
    </body>
  </worldbody>
</mujoco>
"""


def _mujoco():
    try:
        import mujoco
    except ImportError:
        raise TorchhandError("MuJoCo is needed for synthetic captures: pip install 'torchhand[test]'") from None
    return mujoco


def _minjerk(s: float) -> float:
    s = min(max(s, 0.0), 1.0)
    return s ** 3 * (10 - 15 * s + 6 * s * s)


def simulate_presses(settings: TruthSettings, generator: np.random.Generator) -> TruthRun:
    """Simulate ``settings.presses`` presses of the planar finger (module docstring).

    settings:  :class:`TruthSettings`
    generator: NumPy generator for the postures, the reference accelerations and the noise
    returns: :class:`TruthRun`
    """
    mujoco = _mujoco()
    c = settings.compliance
    xml = planar_finger_mjcf(c)
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    surface = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "surface")
    hand_geoms = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, f"{n}_geom") for n in LINKS]
    link_body = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, n) for n in LINKS]
    body_sensor = {b: s for s, b in enumerate(link_body)}
    probe = mujoco.MjData(m)

    def clearance(th):
        probe.qpos[:] = th
        mujoco.mj_kinematics(m, probe)
        return min(mujoco.mj_geomDistance(m, probe, g, surface, 0.1, None) for g in hand_geoms)

    plans = [_plan_press(settings, generator, clearance) for _ in range(settings.presses)]
    hold, ret = 0.1, 0.3
    seg = [hold + p[2] + settings.press_time + ret + hold for p in plans]
    n_sub = int(round(1.0 / (settings.rate * TIMESTEP)))
    dt = n_sub * TIMESTEP
    T = int(sum(seg) / dt)

    def reference(t):
        for k, (th_a, v, t_c, a) in enumerate(plans):
            if t < seg[k]:
                break
            t -= seg[k]
        t1 = t_c + settings.press_time
        if t < hold:
            return th_a
        u = min(t - hold, t1)
        th = th_a + v * u + 0.5 * a * u * u
        if t - hold > t1:
            th = th + (th_a - th) * _minjerk((t - hold - t1) / ret)
        return th

    d.qpos[:] = plans[0][0]
    q = np.zeros((T, 4))
    theta_r = np.zeros((T, 4))
    force = np.zeros((T, 4, 3))
    point = np.zeros((T, 4, 3))
    f6 = np.zeros(6)
    step = 0
    for k in range(T):
        t = k * dt
        th_r = reference(t)
        q[k], theta_r[k] = d.qpos, th_r
        fsum = np.zeros((4, 3))
        psum = np.zeros((4, 3))
        for i in range(d.ncon):
            con = d.contact[i]
            if con.geom1 == surface or con.geom2 == surface:
                other = con.geom2 if con.geom1 == surface else con.geom1
                s = body_sensor.get(int(m.geom_bodyid[other]))
                if s is None:
                    continue
                mujoco.mj_contactForce(m, d, i, f6)
                fw = con.frame.reshape(3, 3).T @ f6[:3]  # on geom2, world
                fw = fw if con.geom2 == other else -fw
                fsum[s] += fw
                psum[s] += np.linalg.norm(fw) * con.pos
        for s, b in enumerate(link_body):
            n = np.linalg.norm(fsum[s])
            if n > 0:
                p = psum[s] / n
                force[k, s] = fsum[s]
                point[k, s] = d.xmat[b].reshape(3, 3).T @ (p - d.xpos[b])
        for _ in range(n_sub):
            m.qpos_spring[:] = reference(step * TIMESTEP)
            mujoco.mj_step(m, d)
            step += 1
    root = np.tile(np.eye(4), (T, 1, 1))
    root[:, 2, 3] = ROOT_HEIGHT
    truth = np.concatenate([np.full(6, np.nan), c])
    common = dict(joint_names=JOINTS, root_pose=root, fps=settings.rate, force_point=point, force_link=LINKS,
                  hand="planar_finger.xml", source="synthetic", truth_compliance=truth)
    clean = Capture(q=q, force=force, **common)
    noisy = Capture(q=q + generator.normal(0.0, math.radians(settings.noise_angle_deg), q.shape),
                    force=force + generator.normal(0.0, settings.noise_force, force.shape), **common)
    starts = np.cumsum([0.0] + seg[:-1])
    return TruthRun(capture=noisy, clean=clean, theta_r=theta_r,
                    contact_time=starts + hold + np.array([p[2] for p in plans]), mjcf=xml)


def _plan_press(settings: TruthSettings, rng: np.random.Generator, clearance):
    """A start posture 12-35 mm above the plane (contact 90-300 ms after the reference starts moving), a flexion
    direction and rate, and the predicted contact time."""
    for _ in range(1000):
        th_a = np.array([rng.uniform(0.0, 0.3), rng.uniform(0.0, 0.5), rng.uniform(0.1, 0.6),
                         rng.uniform(0.1, 0.5)])
        h0 = clearance(th_a)
        if not 0.012 <= h0 <= 0.035:
            continue
        direction = rng.uniform(0.2, 1.0, 4)
        eps = 1e-4
        rate = (clearance(th_a + eps * direction) - h0) / eps  # metres per unit of reference advance
        if rate >= -0.02:
            continue
        v = direction * settings.approach_speed / -rate  # rad/s
        a = rng.uniform(-settings.max_accel, settings.max_accel, 4)
        t = 0.0
        while t < 0.3 and clearance(th_a + v * t + 0.5 * a * t * t) > 0:
            t += 2e-4
        if 0.09 <= t < 0.3:
            return th_a, v, t, a
    raise InputValueError("could not plan a press of the planar finger (no posture above the plane)")


def write_truth_capture(out_dir, settings: TruthSettings, generator: np.random.Generator) -> tuple[Path, TruthRun]:
    """Simulate and write ``planar_finger.xml`` and ``capture.npz`` into ``out_dir`` (atomically).

    returns: (the capture's path, the :class:`TruthRun`)
    """
    from .._atomic import atomic_text

    run = simulate_presses(settings, generator)
    out = Path(out_dir)
    atomic_text(out / "planar_finger.xml", run.mjcf)
    return save_capture(run.capture, out / "capture.npz"), run


def equilibrium_residual(run: TruthRun, tau: np.ndarray, min_force: float = 0.2) -> np.ndarray:
    """Quasi-static check on the noise-free data: per loaded frame (more than ``min_force`` newtons of contact
    force), max_j |theta_j - theta_r_j - c_j tau_j| / max over the capture of |c tau|.

    tau: J^T f of the noise-free capture, (T, 6 + D) (the root entries are ignored)
    returns: (L,) relative residuals of the L loaded frames
    """
    c = run.clean.truth_compliance[6:]
    loaded = np.linalg.norm(run.clean.force, axis=2).sum(axis=1) > min_force
    ct = c * tau[:, 6:]
    res = run.clean.q - run.theta_r - ct
    return np.abs(res[loaded]).max(axis=1) / max(float(np.abs(ct[loaded]).max(initial=0.0)), 1e-300)
