"""One job of a batch (:class:`Job`): the method, its inputs and options, its id, and its ``torchhand`` command
line."""

from __future__ import annotations

from dataclasses import dataclass

from ._schema import METHOD_OPTIONS

__all__ = ["Job"]


@dataclass(frozen=True)
class Job:
    """One run of a batch: one method on one scene (with one seed and hand, one grasp, or one interaction) and
    fixed options.

    id: ``<prefix>_<hash10>`` (module docstring), the name of its result directory ``DIR/jobs/<id>/``
    method: ``"synthesize"``, ``"manipulate"`` or ``"capture"`` (``torchhand capture resynthesize``)
    scene: a built-in scene name, or the absolute path of a scene directory
    seed: the random seed (synthesize), else None
    hand: ``"default"`` (the scene's own hands) or ``"SIDE=ABSOLUTE_PATH.xml"`` (synthesize); ``"grasp"`` (manipulate:
        the grasp's hand); ``"default"`` (capture: the scene's hand)
    options: (name, value) pairs in the method's option order (:data:`METHOD_OPTIONS`), every option with its
        default filled in; list options (``mass``, ...) as tuples
    inputs: what was hashed for the scene, the hand, the grasp, the interaction (built-in name or SHA-256 of the
        content)
    grasp: manipulate: the absolute path of the grasp file; ``default_grasp``: it is the scene's own (the command
        then finds it itself, ``--grasp`` is left out); else ""
    interaction: capture: the absolute path of the interaction file; else ""
    """

    id: str
    method: str
    scene: str
    seed: int | None
    hand: str
    options: tuple[tuple[str, object], ...]
    inputs: tuple[tuple[str, str], ...]
    grasp: str = ""
    default_grasp: bool = False
    interaction: str = ""

    def argv(self) -> list[str]:
        """The ``torchhand`` command line of the job, without ``--out``, ``--threads``, ``--device`` and
        ``--no-progress`` (the worker adds those its method has). Every option is passed explicitly."""
        if self.method == "manipulate":
            args = ["manipulate", self.scene] + ([] if self.default_grasp else ["--grasp", self.grasp])
        elif self.method == "capture":
            args = ["capture", "resynthesize", self.interaction, "--scene", self.scene]
        else:
            args = [self.method, self.scene, "--seed", str(self.seed)]
        specs = METHOD_OPTIONS[self.method]
        for name, value in self.options:
            spec = specs[name]
            if spec.kind == "bool":
                args += [spec.flag] if value else []
            elif spec.kind == "floats" and value is not None:
                args += [spec.flag, ",".join(str(v) for v in value)]
            elif value is not None:
                args += [spec.flag, str(value)]
        if self.method == "synthesize" and self.hand != "default":
            args += ["--hand", self.hand]
        return args

    def to_dict(self) -> dict:
        out = {"id": self.id, "method": self.method, "scene": self.scene, "seed": self.seed, "hand": self.hand,
               "options": {k: list(v) if isinstance(v, tuple) else v for k, v in self.options},
               "inputs": dict(self.inputs), "argv": self.argv()}
        if self.method == "manipulate":
            out["grasp"] = self.grasp
        if self.method == "capture":
            out["interaction"] = self.interaction
        return out
