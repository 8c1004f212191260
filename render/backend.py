"""The offscreen OpenGL back end: choosing ``PYOPENGL_PLATFORM`` and opening a pyrender context.

Only :func:`offscreen_renderer` (the render entry point) chooses the platform, and only when the user has not set
``PYOPENGL_PLATFORM`` already: EGL when an EGL display can be initialised (NVIDIA's EGL on a GPU, Mesa's
software EGL without one), else OSMesa. Importing :mod:`torchhand` or :mod:`torchhand.render` never touches it.
Failures are :class:`RenderBackendError` with one line that says what to install.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import importlib.util
import os
import sys

from torchhand.errors import TorchhandError

__all__ = ["RenderBackendError", "INSTALL_HINT", "select_platform", "offscreen_renderer"]

_EGL_PLATFORM_DEVICE_EXT = 0x313F
INSTALL_HINT = "apt-get install libegl1 libgl1-mesa-dri libosmesa6"


class RenderBackendError(TorchhandError, RuntimeError):
    """Rendering or video encoding cannot run here (no EGL/OSMesa, no ffmpeg); the message says what to install."""


def _egl_works() -> bool:
    """Whether libEGL loads and one of its devices (as pyrender opens them) or its default display initialises.

    Uses ctypes only: no OpenGL import, no context. Initialising a display loads Mesa's LLVM, so Triton goes first
    (:func:`_load_triton_first`).
    """
    _load_triton_first()
    name = ctypes.util.find_library("EGL")
    if not name:
        return False
    try:
        egl = ctypes.CDLL(name)
        egl.eglGetProcAddress.restype = ctypes.c_void_p
        egl.eglGetProcAddress.argtypes = [ctypes.c_char_p]
        egl.eglInitialize.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p]
        egl.eglTerminate.argtypes = [ctypes.c_void_p]
        displays = []
        query = egl.eglGetProcAddress(b"eglQueryDevicesEXT")
        get_platform_display = egl.eglGetProcAddress(b"eglGetPlatformDisplayEXT")
        if query and get_platform_display:
            devices = (ctypes.c_void_p * 16)()
            count = ctypes.c_int(0)
            proto = ctypes.CFUNCTYPE(ctypes.c_uint, ctypes.c_int, ctypes.POINTER(ctypes.c_void_p),
                                     ctypes.POINTER(ctypes.c_int))
            if proto(query)(16, devices, ctypes.byref(count)):
                opener = ctypes.CFUNCTYPE(ctypes.c_void_p, ctypes.c_uint, ctypes.c_void_p, ctypes.c_void_p)(
                    get_platform_display)
                displays += [opener(_EGL_PLATFORM_DEVICE_EXT, devices[i], None) for i in range(count.value)]
        egl.eglGetDisplay.restype = ctypes.c_void_p
        egl.eglGetDisplay.argtypes = [ctypes.c_void_p]
        displays.append(egl.eglGetDisplay(None))
        for dpy in displays:
            if dpy and egl.eglInitialize(dpy, None, None):
                egl.eglTerminate(dpy)
                return True
        return False
    except (OSError, AttributeError):
        return False


def select_platform() -> str:
    """Choose ``PYOPENGL_PLATFORM`` for offscreen rendering (sets it unless the user already did) and return it.

    Raises:
        RenderBackendError: neither EGL nor OSMesa is available.
    """
    current = os.environ.get("PYOPENGL_PLATFORM")
    if current:
        return current
    if _egl_works():
        platform = "egl"
    elif ctypes.util.find_library("OSMesa"):
        platform = "osmesa"
    else:
        raise RenderBackendError(f"offscreen rendering needs EGL or OSMesa: {INSTALL_HINT}")
    if "OpenGL" in sys.modules:  # PyOpenGL fixed its platform at import; pyrender must agree with it
        loaded = getattr(sys.modules.get("OpenGL.platform"), "PLATFORM", None)
        name = type(loaded).__name__.lower() if loaded is not None else ""
        platform = "egl" if "egl" in name else "osmesa" if "osmesa" in name else platform
    os.environ["PYOPENGL_PLATFORM"] = platform
    return platform


def _load_triton_first() -> None:
    """Import Triton (present with CUDA builds of torch) before the first OpenGL context, if it is installed.

    Mesa's software rasteriser (llvmpipe, under EGL and OSMesa; already when an EGL display is initialised) loads its
    own LLVM; importing Triton after that crashes the process (a segmentation fault in Triton's extension, seen with
    torch 2.15 + Triton on Mesa 22), and torch imports Triton lazily, e.g. when an optimizer is created. Loaded
    first, both work.
    """
    if "triton" in sys.modules or importlib.util.find_spec("triton") is None:
        return
    try:
        import triton  # noqa: F401
    except Exception:  # noqa: BLE001 - a Triton that cannot load is torch's concern, not the renderer's
        pass


def offscreen_renderer(width: int, height: int):
    """A ``pyrender.OffscreenRenderer`` of ``width`` x ``height`` pixels on the chosen platform.

    Raises:
        RenderBackendError: pyrender is not installed or no offscreen OpenGL context can be created.
    """
    _load_triton_first()
    platform = select_platform()
    try:
        import pyrender
    except ImportError as err:
        raise RenderBackendError(f"rendering needs pyrender (the maintained fork pyrender2): pip install 'pyrender2>=0.2.2' ({err})") from None
    try:
        return pyrender.OffscreenRenderer(int(width), int(height))
    except Exception as err:  # noqa: BLE001 - any GL/EGL failure becomes one actionable line
        reason = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        if platform == "osmesa" and "OSMesaCreateContextAttribs" in reason:
            reason += "; OSMesa needs PyOpenGL >= 3.1.5"
        raise RenderBackendError(f"offscreen rendering needs EGL or OSMesa (PYOPENGL_PLATFORM={platform} failed: "
                                 f"{reason}): {INSTALL_HINT}") from None
