"""What the search needs to know about a scene, computed once: hands, SDF, required wrenches, contact patches.

:func:`build_problem` turns a :class:`~torchhand.scene.Scene` into a frozen :class:`SynthesisProblem`:

* the hand models (one per wrist track) and their root poses;
* the object's SDF grid, its surface samples (object frame) and per-frame poses;
* the wrench the contacts must produce in every frame (Newton–Euler from finite differences of the object pose:
  ``F = m (a - g)``, ``tau = I_w alpha + omega x I_w omega`` about the centre of mass, world frame, less the
  scene's ``external_wrench`` when it has one);
* the object-table contacts (static or sliding, known from the object motion, Ye & Liu §4.3);
* the contact patches of §4.2's initial case: for every frame and finger, the object-surface samples that lie in
  the fingertip's reachable volume (a voxelised cloud of fingertip positions over random finger poses, in the
  wrist frame, dilated by one voxel).

Conventions (:mod:`torchhand.conventions`): metres, seconds, newtons; world z up; poses ``T_world_frame``;
contact normals point into the object; wrench = (force, torque about the centre of mass), world.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import torch
from kornia.geometry.conversions import rotation_matrix_to_axis_angle

from ..hand.collision import rigid_inverse
from ..errors import ShapeError
from ..hand.mount import track_hand
from ..hand.model import HandModel
from ..geometry.objects import sample_surface
from ..scene import EnvContacts, Scene, environment_contacts
from ..geometry.sdf import SDFGrid

__all__ = ["SynthesisProblem", "build_problem", "required_wrench", "finger_workspace", "node_context",
           "frames_key"]


@dataclass(frozen=True, eq=False)
class SynthesisProblem:
    """A scene prepared for the search (H hands, F fingers per hand, T frames, S object-surface samples).

    hands:        tuple of H :class:`HandModel` (same link / joint layout), on the working device and dtype
    sides:        tuple of H side names ("right" / "left")
    root:         wrist poses ``T_world_hand``, (H, T, 4, 4), world, metres
    object_pose:  ``T_world_object``, (T, 4, 4); object_inv: its inverse, (T, 4, 4)
    com:          centre of mass, (T, 3), world, metres
    wrench:       required net wrench on the object from all contacts, (T, 6): force (N), torque about the COM (N m)
    sdf:          the object's SDF grid, object frame
    surface:      object-surface samples, (S, 3), object frame, metres; surface_normal: outward, (S, 3)
    patch:        whether sample s is in finger f of hand h's reachable volume at frame t, (H, F, T, S) bool
    env:          object-table contacts (:class:`EnvContacts`, T frames, E slots)
    env_friction: object-table friction coefficient; friction: hand-object friction coefficient
    mass:         object mass, kg; weight: m |g|, newtons (the force scale of the checks)
    fps:          frames per second
    table_height: z of the table plane, world, metres; None without a table (the hands must stay above it) and
                  for a table with an edge or a floor, which ``ground`` describes instead
    ground:       the table block and floor (:class:`~torchhand.geometry.ground.Ground`) that the hands must stay
                  out of, when the environment is not a plain table (``Environment.plain``); None otherwise
    mesh:         the object's trimesh.Trimesh, object frame (exact normals in the final check), or None
    """

    hands: tuple
    sides: tuple
    root: torch.Tensor
    object_pose: torch.Tensor
    object_inv: torch.Tensor
    com: torch.Tensor
    wrench: torch.Tensor
    sdf: SDFGrid
    surface: torch.Tensor
    surface_normal: torch.Tensor
    patch: torch.Tensor
    env: EnvContacts
    env_friction: float
    friction: float
    mass: float
    weight: float
    fps: float
    table_height: float | None = None
    mesh: object = None
    ground: object = None

    @property
    def T(self) -> int:
        return int(self.object_pose.shape[0])

    @property
    def H(self) -> int:
        return len(self.hands)

    @property
    def F(self) -> int:
        return self.hands[0].num_fingers

    @property
    def dtype(self) -> torch.dtype:
        return self.object_pose.dtype

    @property
    def device(self) -> torch.device:
        return self.object_pose.device


_STATIC = ("hands", "sdf", "mesh", "ground")
_FRAMES = ("root", "object_pose", "object_inv", "com", "wrench", "env")
_VALUES = ("env_friction", "friction", "mass", "weight", "fps", "table_height")


def node_context(problem: SynthesisProblem) -> tuple:
    """What the node test reads of ``problem`` apart from its frames: the identities of its models, SDF, mesh and
    ground, its scalars, its table-contact slots, dtype and device. Problems with the same context can be tested in
    one call (their frames stacked when they differ, :func:`.multi.stack_frames`)."""
    return (tuple(id(getattr(problem, f)) for f in _STATIC) + tuple(getattr(problem, f) for f in _VALUES)
            + (int(problem.env.mask.shape[1]), problem.dtype, str(problem.device)))


def frames_key(problem: SynthesisProblem) -> tuple:
    """The identities of ``problem``'s frame tensors: equal for the seeds of one scene (``build_problem``'s
    ``share``), which are then one problem to the node test."""
    return tuple(id(getattr(problem, f)) for f in _FRAMES)


def required_wrench(object_pose: torch.Tensor, com_local: torch.Tensor, mass: float, inertia: torch.Tensor,
                    gravity: torch.Tensor, fps: float, external: torch.Tensor | None = None
                    ) -> tuple[torch.Tensor, torch.Tensor]:
    """Newton–Euler wrench the contacts must apply to follow the object trajectory.

    object_pose: (T, 4, 4) world; com_local: (3,) object frame; inertia: (3, 3) about the COM, object axes;
    gravity: (3,) m/s^2; external: a known wrench acting ON the object besides gravity and the contacts
    (:attr:`torchhand.scene.Scene.external_wrench`), (T, 6), force (N) and torque about the COM (N m), world, or
    None. Velocities and accelerations are central finite differences (one-sided at the ends, zero for a single
    frame); angular velocity from the rotation log (kornia) of consecutive frames.
    Returns (com (T, 3) world, wrench (T, 6)): what the contacts must supply, ``(m (a - g), I_w alpha + omega x
    I_w omega) - external``.
    """
    T = object_pose.shape[0]
    R = object_pose[:, :3, :3]
    com = (R @ com_local[:, None]).squeeze(-1) + object_pose[:, :3, 3]
    acc = torch.zeros_like(com)
    omega = torch.zeros_like(com)
    alpha = torch.zeros_like(com)
    if T >= 3:
        acc[1:-1] = (com[2:] - 2 * com[1:-1] + com[:-2]) * fps * fps
        acc[0], acc[-1] = acc[1], acc[-2]
    if T >= 2:
        # omega at the midpoints t + 1/2 from R_{t+1} R_t^T (world-frame increments), then averaged to frames
        dR = R[1:] @ R[:-1].transpose(-1, -2)
        w_mid = rotation_matrix_to_axis_angle(dR) * fps
        omega[1:-1] = 0.5 * (w_mid[1:] + w_mid[:-1])
        omega[0], omega[-1] = w_mid[0], w_mid[-1]
        if T >= 3:
            alpha[1:-1] = (w_mid[1:] - w_mid[:-1]) * fps
            alpha[0], alpha[-1] = alpha[1], alpha[-2]
    I_w = R @ inertia @ R.transpose(-1, -2)
    Iw = (I_w @ omega[..., None]).squeeze(-1)
    torque = (I_w @ alpha[..., None]).squeeze(-1) + torch.cross(omega, Iw, dim=-1)
    force = mass * (acc - gravity)
    wrench = torch.cat([force, torque], -1)
    if external is not None:
        if tuple(external.shape) != (T, 6):
            raise ShapeError(f"external: expected shape ({T}, 6) (as object_pose's T), got {tuple(external.shape)}")
        wrench = wrench - external.to(dtype=wrench.dtype, device=wrench.device)
    return com, wrench


def finger_workspace(hand: HandModel, generator: torch.Generator, samples: int = 4096,
                     voxel: float = 0.006) -> list[torch.Tensor]:
    """Voxelised reachable volume of each fingertip pad in the wrist frame.

    Random finger poses within the joint limits (uniform, from ``generator``), fingertip pads by FK with the
    identity root. Returns, per finger, the occupied voxel keys (int64 codes of (i, j, k) at ``voxel`` metres,
    dilated by one voxel), sorted, for :func:`_in_workspace`.
    """
    q = hand.random_q(samples, generator)
    T = hand.forward_kinematics(q)
    tips = (T[:, hand.distal_link, :3, :3] @ hand.fingertip[None, :, :, None]).squeeze(-1) \
        + T[:, hand.distal_link, :3, 3]                                        # (N, F, 3)
    out = []
    offsets = torch.stack(torch.meshgrid(*(torch.arange(-1, 2),) * 3, indexing="ij"), -1).reshape(-1, 3)
    for f in range(hand.num_fingers):
        ijk = torch.floor(tips[:, f] / voxel).long()
        ijk = (ijk[:, None, :] + offsets[None]).reshape(-1, 3)
        out.append(torch.unique(_code(ijk)))
    return out


def _code(ijk: torch.Tensor) -> torch.Tensor:
    """(…, 3) int voxel indices -> (…,) int64 codes (indices within +-2^19)."""
    b = ijk + (1 << 19)
    return (b[..., 0] << 40) | (b[..., 1] << 20) | b[..., 2]


def _in_workspace(points_hand: torch.Tensor, codes: torch.Tensor, voxel: float) -> torch.Tensor:
    """Whether points (…, 3) in the wrist frame fall in the voxel set ``codes`` (sorted). Returns (…,) bool."""
    c = _code(torch.floor(points_hand / voxel).long())
    pos = torch.searchsorted(codes, c.reshape(-1)).clamp_max(codes.numel() - 1)
    return (codes[pos] == c.reshape(-1)).reshape(c.shape)


def _thin_env(env: EnvContacts, most: int) -> EnvContacts:
    """At most ``most`` table contacts per frame, by farthest-point selection among each frame's support points
    (a round base touches with dozens of hull vertices; a few spread along the rim span nearly the same support
    polygon, which keeps the dynamic test small). Deviation: the support polygon shrinks to the chosen points."""
    T, E = env.mask.shape
    if E <= most:
        return env
    keep = torch.zeros(T, most, dtype=torch.long)
    for t in range(T):
        idx = env.mask[t].nonzero().squeeze(-1)
        if idx.numel() <= most:
            keep[t, :idx.numel()] = idx
            keep[t, idx.numel():] = E                                   # padding (index of an appended empty slot)
            continue
        pts = env.points[t, idx]
        chosen = [0]
        d = (pts - pts[0]).norm(dim=-1)
        for _ in range(most - 1):
            j = int(d.argmax())
            chosen.append(j)
            d = torch.minimum(d, (pts - pts[j]).norm(dim=-1))
        keep[t] = idx[torch.tensor(chosen)]

    def pick(x, fill):
        pad = torch.full_like(x[:, :1], fill) if x.dim() == 2 else torch.zeros_like(x[:, :1])
        xx = torch.cat([x, pad], 1)
        return torch.gather(xx, 1, keep if x.dim() == 2 else keep[..., None].expand(-1, -1, x.shape[-1]))

    return EnvContacts(points=pick(env.points, 0), mask=pick(env.mask, False),
                       sliding_velocity=pick(env.sliding_velocity, 0), support_index=pick(env.support_index, -1),
                       normal=env.normal)


def build_problem(scene: Scene, generator: torch.Generator, *, device="cpu", dtype=torch.float32,
                  voxel_size: float = 0.0015, surface_samples: int = 3000, max_env_contacts: int = 8,
                  progress: bool = False, share: SynthesisProblem | None = None,
                  statics: SynthesisProblem | None = None) -> SynthesisProblem:
    """Prepare ``scene`` for the search (see the module docstring). Randomness only from ``generator`` (CPU): the
    surface samples and the finger workspaces (so the contact patches), nothing else.

    share: a problem built from the same scene with the same device, dtype and settings (another seed's): its
    hands, poses, wrenches, SDF, table contacts and mesh are reused (the same objects, so the searches of both
    can be tested in one node-test call, :mod:`.multi`) and only the seed's samples and patches are drawn. The
    result is the same as without it. statics: a problem of another frame range of the same scene (the windows of
    a capture, ``Scene.with_frames``), same device, dtype and settings: its hand models, SDF, mesh and ground are
    reused (the same objects: the searches of both can share node-test calls, :mod:`.multi`), the rest is this
    scene's; the result equals one built without it."""
    pose64 = scene.object_pose.double()
    pts, nrm = sample_surface(scene.object.mesh, surface_samples, generator, dtype=torch.float64)
    patch = _patches(scene, pose64, pts, generator).to(device)
    if share is not None:
        return dataclasses.replace(share, surface=pts.to(device, dtype), surface_normal=nrm.to(device, dtype),
                                   patch=patch)
    if statics is not None and (len(statics.hands) != len(scene.hands) or statics.mesh is not scene.object.mesh):
        raise ShapeError("statics: expected a problem of the same object mesh and hands as the scene")
    hands = statics.hands if statics is not None else tuple(track_hand(track).to(device, dtype)
                                                             for track in scene.hands)
    root = torch.stack([track.wrist_pose for track in scene.hands]).to(device, dtype)
    obj = scene.object
    com64, wrench64 = required_wrench(pose64, torch.tensor(np.array(obj.com), dtype=torch.float64), obj.mass,
                                      torch.tensor(np.array(obj.inertia), dtype=torch.float64), scene.gravity.double(),
                                      scene.fps, external=scene.external_wrench)
    sdf = statics.sdf if statics is not None else SDFGrid.from_mesh(obj.mesh, voxel_size, progress=progress).to(
        device, dtype)
    env = _thin_env(environment_contacts(scene), max_env_contacts)
    return SynthesisProblem(
        hands=hands, sides=tuple(t.side for t in scene.hands), root=root,
        object_pose=pose64.to(device, dtype), object_inv=rigid_inverse(pose64).to(device, dtype),
        com=com64.to(device, dtype), wrench=wrench64.to(device, dtype), sdf=sdf,
        surface=pts.to(device, dtype), surface_normal=nrm.to(device, dtype), patch=patch,
        env=EnvContacts(env.points.to(device, dtype), env.mask.to(device), env.sliding_velocity.to(device, dtype),
                        env.support_index.to(device), env.normal.to(device, dtype)),
        env_friction=float(scene.environment.friction), friction=float(scene.friction), mass=float(obj.mass),
        weight=float(obj.mass * scene.gravity.norm()), fps=float(scene.fps),
        table_height=float(scene.environment.table_height) if scene.environment.table and scene.environment.plain
        else None, mesh=obj.mesh, ground=None if scene.environment.plain else
        statics.ground if statics is not None else scene.environment.ground())


def _patches(scene: Scene, pose64: torch.Tensor, pts: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
    """The contact patches (H, F, T, S) bool of the surface samples ``pts`` (S, 3) object frame, float64, under the
    object poses ``pose64`` (T, 4, 4): each hand's finger workspaces drawn from ``generator``."""
    # points in the wrist frame of every hand and frame: (H, T, S, 3)
    world = torch.einsum("tij,sj->tsi", pose64[:, :3, :3], pts) + pose64[:, None, :3, 3]
    patches = []
    for track in scene.hands:
        inv = rigid_inverse(track.wrist_pose.double())
        local = torch.einsum("tij,tsj->tsi", inv[:, :3, :3], world) + inv[:, None, :3, 3]
        codes = finger_workspace(track_hand(track), generator)
        patches.append(torch.stack([_in_workspace(local, c, 0.006) for c in codes]))   # (F, T, S)
    return torch.stack(patches)
