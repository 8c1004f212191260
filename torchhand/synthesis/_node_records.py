"""Records of the node test (:mod:`.node_test`): guiding configurations, settings, per-frame results and the cause
and force-class codes."""

from __future__ import annotations

from dataclasses import dataclass

import torch




CAUSE_NONE, CAUSE_KINEMATIC, CAUSE_FINGERS, CAUSE_DYNAMIC = 0, 1, 2, 3
FORCE_ZERO, FORCE_INSIDE, FORCE_BOUNDARY = 0, 1, 2


@dataclass(frozen=True)
class Guides:
    """Guiding configurations c (Ye & Liu §3): at most one guiding point per finger, N candidates.

    active: finger has a guiding point, (N, H, F) bool
    link:   link (index within its hand) carrying the hand point p.h, (N, H, F) long
    local:  the hand point p.h in that link's frame, (N, H, F, 3), metres
    obj:    the object point p.o, (N, H, F, 3), object frame, metres
    slide:  unit direction in which p.o moves along the surface this frame (sliding contact), (N, H, F, 3), object
            frame; zeros for a static contact
    roll:   rolling contact, (N, H, F) bool, or None (none rolls): p.h is not fixed but is the point of its link's
            capsule that faces p.o, re-chosen as the finger moves, so the contact moves on the finger while p.o
            stays on the object
    """

    active: torch.Tensor
    link: torch.Tensor
    local: torch.Tensor
    obj: torch.Tensor
    slide: torch.Tensor
    roll: torch.Tensor | None = None

    def rows(self, index: torch.Tensor) -> "Guides":
        """The guides of the candidates ``index`` (n,) long."""
        return Guides(self.active[index], self.link[index], self.local[index], self.obj[index], self.slide[index],
                      None if self.roll is None else self.roll[index])


@dataclass(frozen=True)
class NodeTestSettings:
    """Tolerances and iteration counts of the node test (metres, radians)."""

    dq: float = 0.3                # |q - q_prev| bound per frame (Eq. 3), radians
    dq_free: float = 0.6           # the same bound for fingers without a guiding point
    ik_iters: int = 20             # LM iterations
    ik_tol: float = 0.002          # a guiding point farther than this from its target fails the finger
    nail_cos: float = 0.0          # Eq. 2: nail . outward normal >= nail_cos
    nail_weight: float = 0.02      # metres per unit of nail misalignment
    reg_weight: float = 0.003      # pull toward the initial pose, metres per radian
    damping: float = 1e-7
    pen_tol: float = 0.001         # deepest allowed penetration of a link capsule (SDF), metres
    push_margin: float = 0.0003    # capsules are kept this far outside the surface, metres
    contact_dist: float = 0.0012   # a link's closest sample within this distance is a contact, metres
    finger_tol: float = 0.001      # finger-finger capsule overlap allowed, metres
    env_weight: float = 0.5        # objective weight of table contacts (Eq. 4); 0 makes the optimum degenerate
    balance_tol: float = 1e-3      # an unfinished force solve still counts when its wrench residual is below this
    #                                times the object's weight (forces are cone-feasible by construction)
    edge_proxies: bool = True      # area-contact proxies near sharp edges (Ye & Liu §7)
    proxy_radius: float = 0.003    # proxies are tried this far from a fingertip contact on the surface, metres
    proxy_cos: float = 0.9         # a proxy counts where its normal turns more than acos(proxy_cos) (~26 deg)
    proxy_dist: float = 0.0015     # ... and the fingertip's capsule is within this distance of it, metres
    boundary: float = 0.97         # |f_t| >= boundary mu f_n: the force is on the cone's boundary
    zero_force: float = 1e-3       # f_n below zero_force * weight: no force
    slide_speed: float = 0.02      # a held contact moving on the object faster than this slides, m/s
    table_slide_speed: float = 1e-3  # a table contact moving slower than this is static, m/s (the scene's own
    #                                rule, scene._contacts.environment_contacts); a capture uses its slide speed,
    #                                the capture's noise, for hand and table contacts alike (torchhand.fill)
    cone_iters: int | None = 300   # iteration limit of the friction-cone solver (None: its default); a search
    #                                can drop the rare hard problem, the final check gives it more
    cone_retry_iters: int | None = 3000   # a force solve left undecided at cone_iters (neither converged, nor
    #                                certified infeasible, nor within balance_tol) is resumed from its forces up to
    #                                this many iterations of plain ADMM before its verdict counts (None: no second
    #                                try); a thin open-hand contact set can need ~2000 (a rod's frame 6: residual
    #                                2.9e-3 at 300, 2.5e-5 at 2000; tests/torchhand/test_node_verdicts.py)
    cone_polish: bool = True       # Newton polishing inside the friction-cone solver ...
    cone_polish_from: int | None = 250   # ... from this iteration on (of cone_iters = 300): plain ADMM settles
    #                                most search problems at cone_tol, Newton steps go to the slow ones only
    #                                (box-turn's search 1.4x faster than polishing from iteration 20; without
    #                                any polishing the ManipNet mug loses half its feasible frames to unfinished
    #                                solves)
    cone_tol: float | None = 1e-4  # its relative tolerance (None: its per-dtype default); the search needs the
    #                                verdict, not six digits; the final check of the pipeline uses the default
    exact: bool = False            # final-check mode: contact normals from the mesh (CPU, trimesh; :mod:`.exact`)
    max_force: float = 30.0        # a frame needing a larger force at any contact fails the dynamic test, newtons
    #                                (or max_force_weights times the object's weight, whichever is larger): a grip
    #                                that balances only by squeezing with 100 N is a degenerate contact set that the
    #                                mesh's exact normals no longer balance (Liu 2009 caps forces at 30 N too)
    max_force_weights: float = 5.0


@dataclass(frozen=True)
class FrameResult:
    """Outcome of the node test for N candidates.

    q:           finger joint angles, (N, H, D), radians
    feasible:    (N,) bool; cause: (N,) int, CAUSE_* of the first failure (kinematic > fingers > dynamic)
    kin_fail:    fingers that failed the kinematic test, (N, H, F) bool
    pair:        global finger indices (h F + f) of the deepest finger-finger overlap, (N, 2) long, -1 if none
    c_mask:      hand contacts, (N, K) bool, K = H L + H F (:func:`contact_slots`)
    c_local:     hand point of each contact in its link's frame, (N, K, 3); c_point: contact point on the object
                 surface, (N, K, 3) world; c_normal: into the object, (N, K, 3); c_force: force of the hand on the
                 object, (N, K, 3) world, newtons (zero unless the dynamic test ran and converged); c_sliding:
                 contacts held since the previous frame whose hand point slides on the object, (N, K) bool
    env_force:   (N, E, 3) world, newtons
    penetration: deepest penetration of any link capsule, (N,), metres (>= 0)
    guide_err:   distance of each guiding point from its target, (N, H, F), metres (0 where inactive)
    seed_*:      per finger, its most distal contact (Ye & Liu §4.2 seeds): seed_on (N, H, F) bool, seed_link
                 (N, H, F) long, seed_local (N, H, F, 3) link frame, seed_obj (N, H, F, 3) object frame,
                 seed_class (N, H, F) long FORCE_*, seed_tdir (N, H, F, 3) unit tangential force, object frame
    """

    q: torch.Tensor
    feasible: torch.Tensor
    cause: torch.Tensor
    kin_fail: torch.Tensor
    pair: torch.Tensor
    c_mask: torch.Tensor
    c_sliding: torch.Tensor
    c_local: torch.Tensor
    c_point: torch.Tensor
    c_normal: torch.Tensor
    c_force: torch.Tensor
    env_force: torch.Tensor
    penetration: torch.Tensor
    guide_err: torch.Tensor
    seed_on: torch.Tensor
    seed_link: torch.Tensor
    seed_local: torch.Tensor
    seed_obj: torch.Tensor
    seed_class: torch.Tensor
    seed_tdir: torch.Tensor
