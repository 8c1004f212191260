"""Whole captures: fill in the fingers of an entire motion capture (``torchhand fill``).

A capture is segmented into phases from the object's motion and the hand-object distance
(:mod:`torchhand.fill.phases`), each contact phase is synthesized in overlapping windows (independent searches
with their own seeds), and the windows are stitched into one motion per hand covering every frame. The capture's
own noise sets the search's slide speed (:mod:`torchhand.fill.noise`); where the capture has finger joints, the
synthesized fingers are compared with them (:mod:`torchhand.fill.reference`).

Conventions (see :mod:`torchhand.conventions`): scene frames, metres, seconds, radians; frame ranges are
``[start, stop)``.
"""
