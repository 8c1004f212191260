"""Offscreen rendering (installed as ``torchhand.render``). pyrender is imported lazily by the entry points."""
