"""Nimbus from Python: physically based rendering of clouds.

A numpy density in, images, metrics and RPNN training records out; every estimator of the
``nimbus`` command line (``pt``, ``pt-gpu``, ``pm``, ``pm-march``, ``pm-elek2012``, ``rpnn``,
``rpnn-dirs``) with the same settings and the same pixels for the same seed.

>>> vol = nimbus.Volume.from_numpy(density, aabb_min=(-1, -.75, -1), aabb_max=(1, .75, 1))
>>> scene = nimbus.Scene(volume=vol, density_scale=40.0, phase=nimbus.HenyeyGreenstein(0.857),
...                      sun=nimbus.Sun(direction=(1, .35, -.1)),
...                      camera=nimbus.Camera(origin=(0, .1, 4.2), target=(0, 0, 0), vfov_deg=26,
...                                           width=128, height=96))
>>> img = nimbus.render(scene, method="pt", spp=64, seed=7)
>>> img.rgb.shape
(96, 128, 3)

See docs/python.md.
"""

import os as _os
from pathlib import Path as _Path


def _find_onnxruntime():
    """The ONNX Runtime library of the ``onnxruntime`` wheel this package depends on, given to
    the network's loader through ``ORT_DYLIB_PATH`` (unless that is set already)."""
    if _os.environ.get("ORT_DYLIB_PATH"):
        return
    import importlib.util

    spec = importlib.util.find_spec("onnxruntime")
    if spec is None or not spec.submodule_search_locations:
        return
    for root in spec.submodule_search_locations:
        capi = _Path(root) / "capi"
        libs = sorted(capi.glob("libonnxruntime.so*")) + sorted(capi.glob("libonnxruntime*.dylib"))
        libs += sorted(capi.glob("onnxruntime.dll"))
        if libs:
            _os.environ["ORT_DYLIB_PATH"] = str(libs[-1])
            return


def _find_models():
    """The RPNN models shipped inside the package, unless ``NIMBUS_MODELS`` names a folder."""
    if _os.environ.get("NIMBUS_MODELS"):
        return
    shipped = _Path(__file__).parent / "models"
    if (shipped / "rpnn-hg.onnx").is_file():
        _os.environ["NIMBUS_MODELS"] = str(shipped)


_find_onnxruntime()
_find_models()

from ._nimbus import (  # noqa: E402
    Camera,
    Estimator,
    HenyeyGreenstein,
    Image,
    Isotropic,
    Mie,
    Phase,
    Scene,
    Sky,
    Sun,
    Volume,
    compare,
    compare_scene,
    datagen,
    generate,
    max_memory,
    methods,
    render,
    set_threads,
    settings,
    tau,
    threads,
)

__all__ = [
    "Camera",
    "Estimator",
    "HenyeyGreenstein",
    "Image",
    "Isotropic",
    "Mie",
    "Phase",
    "Scene",
    "Sky",
    "Sun",
    "Volume",
    "compare",
    "compare_scene",
    "datagen",
    "generate",
    "max_memory",
    "methods",
    "render",
    "set_threads",
    "settings",
    "tau",
    "threads",
]
