"""The working state of one planning run (:mod:`.plan`): the geometry fixed over the run (:class:`_Geometry`: object
motion, required wrench, table contacts, hand surface) and the hand contacts in the object frame (:class:`_Contacts`),
with the grasp's initial contacts and the adding of one contact."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from ..kernels.frames import tangent_frame
from ._plan_records import PlanSettings
from .grasp import Grasp
from .snap import hand_surface_in_object, signed_distance


@dataclass
class _Contacts:
    """Hand contacts (object frame) and the candidates for new ones (mutable working state of one planning run)."""

    link: list           # link index per contact
    h: list              # link-local hand point (3,)
    p: list              # object-frame point (3,)
    n: list              # object-frame normal into the object (3,)
    t1: list             # object-frame first tangent (3,)
    start: list          # first active frame
    source: list         # slot it was generated from (-1)
    h_obj: list          # the hand point in the object frame at the grasp pose (3,)
    slide: dict = field(default_factory=dict)   # contact -> world velocity of its hand point relative to the object
                                                # point at k-1, for contacts sliding into frame k (hand synthesis)


def _normal_frame(n: np.ndarray) -> np.ndarray:
    t1, _ = tangent_frame(torch.as_tensor(n, dtype=torch.float64)[None])
    return t1[0].numpy()


class _Geometry:
    """Everything fixed over a run: the object's motion and required wrench, the table contacts, the hand surface at
    the grasp pose (object frame) and the object mesh."""

    def __init__(self, scene, grasps, hands, settings: PlanSettings):
        from ..scene import environment_contacts
        from ..synthesis.problem import _thin_env, required_wrench

        obj = scene.object
        mass = float(settings.mass if settings.mass is not None else obj.mass)
        inertia = torch.tensor(np.array(obj.inertia), dtype=torch.float64) * (mass / float(obj.mass))
        pose = scene.object_pose.double()
        com, wrench = required_wrench(pose, torch.tensor(np.array(obj.com), dtype=torch.float64), mass, inertia,
                                      scene.gravity.double(), scene.fps, external=scene.external_wrench)
        self.T = int(pose.shape[0])
        self.pose = pose.numpy()
        self.com, self.wrench = com.numpy(), wrench.numpy()
        self.wrench_required = self.wrench.copy()        # self.wrench: as planned (within the deficit allowance)
        self.weight = mass * float(torch.linalg.vector_norm(scene.gravity.double()))
        self.extent = float(np.max(obj.mesh.extents))
        self.mu = float(settings.friction if settings.friction is not None else scene.friction)
        self.mu_env = float(scene.environment.friction)
        env = _thin_env(environment_contacts(scene), settings.max_env_contacts)
        self.env_points = env.points.double().numpy()                       # (T, E, 3)
        self.env_mask = env.mask.numpy()
        self.env_slide = -env.sliding_velocity.double().numpy()             # table point relative to object point
        self.E = int(self.env_mask.shape[1])
        self.mesh = obj.mesh
        # one or two hands; links are numbered across them: hand j's link l is link_offset[j] + l
        grasps = [grasps] if isinstance(grasps, Grasp) else list(grasps)
        self.hands = list(hands) if isinstance(hands, (list, tuple)) else [hands]
        self.hand = self.hands[0]
        self.sides = [g.side for g in grasps]
        self.link_offset = np.cumsum([0] + [h.num_links for h in self.hands])
        self.sample_link = np.concatenate([h.sample_link.cpu().numpy() + o for h, o in zip(self.hands,
                                                                                          self.link_offset)])
        self.sample_local = np.concatenate([h.sample_points.detach().cpu().double().numpy() for h in self.hands])
        self.sample_hand = np.concatenate([np.full(h.sample_link.numel(), j) for j, h in enumerate(self.hands)])
        self.q_now = [np.asarray(g.q, dtype=np.float64) for g in grasps]
        self.wrist_now = [np.asarray(g.wrist_in_object, dtype=np.float64) for g in grasps]
        self.samples = np.zeros((len(self.sample_link), 3))
        self.link_pose = np.zeros((int(self.link_offset[-1]), 4, 4))
        for j in range(len(self.hands)):
            self._pose_hand(j)
        self._moved: dict = {}
        # Reachability of added contacts (set by the manipulation loop, which moves the hand; None: planning alone,
        # a rigid grasp, where any link may take a contact): the joint step per frame the synthesis allows, rad.
        self.reach_step: float | None = None

    def move_hand(self, q: np.ndarray, wrist_in_object: np.ndarray, j: int = 0) -> None:
        """Hand j's current pose (joint angles (D,), wrist in the object frame (4, 4)): new contacts (Sec. 4.3)
        are chosen from the hand surface there (computed when a contact is added)."""
        self._moved[j] = (np.asarray(q, dtype=np.float64), np.asarray(wrist_in_object, dtype=np.float64))

    def _pose_hand(self, j: int) -> None:
        hand, q, w = self.hands[j], self.q_now[j], self.wrist_now[j]
        self.samples[self.sample_hand == j] = hand_surface_in_object(hand, q, w)
        lo, hi = self.link_offset[j], self.link_offset[j + 1]
        self.link_pose[lo:hi] = (torch.as_tensor(w) @ hand.forward_kinematics(torch.as_tensor(q)[None])[0]).numpy()

    def _refresh(self) -> None:
        for j, (q, w) in self._moved.items():
            self.q_now[j], self.wrist_now[j] = q, w
            self._pose_hand(j)
        self._moved = {}

    def hand_of(self, link: int) -> int:
        """The hand (index into ``hands``) of a numbered link."""
        return int(np.searchsorted(self.link_offset, link, side="right") - 1)

    def link_name(self, link: int) -> str:
        """A numbered link's name; with two hands ``<side>/<link>`` (the result files' convention)."""
        j = self.hand_of(link)
        name = self.hands[j].link_names[link - self.link_offset[j]]
        return name if len(self.hands) == 1 else f"{self.sides[j]}/{name}"


def _initial_contacts(geo: _Geometry, grasps) -> _Contacts:
    c = _Contacts([], [], [], [], [], [], [], [])
    for j, grasp in enumerate([grasps] if isinstance(grasps, Grasp) else grasps):
        _, _, nrm = signed_distance(geo.mesh, grasp.contact_object)
        for name, h, p, n_out in zip(grasp.contact_links, grasp.contact_hand, grasp.contact_object, nrm):
            _add(c, geo, geo.link_offset[j] + geo.hands[j].link_index(name), h, p, -n_out, 0, -1)
    return c


def _add(c: _Contacts, geo: _Geometry, link: int, h, p, n, start: int, source: int) -> None:
    geo._refresh()
    n = np.asarray(n, dtype=np.float64)
    n = n / np.linalg.norm(n)
    T = geo.link_pose[link]
    c.link.append(int(link)), c.h.append(np.asarray(h, dtype=np.float64)), c.p.append(np.asarray(p, dtype=np.float64))
    c.n.append(n), c.t1.append(_normal_frame(n)), c.start.append(int(start)), c.source.append(int(source))
    c.h_obj.append(T[:3, :3] @ np.asarray(h, dtype=np.float64) + T[:3, 3])
