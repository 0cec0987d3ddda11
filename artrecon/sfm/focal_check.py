"""Given intrinsics against the images: the focal length the images support.

SfM holds given intrinsics fixed (:func:`artrecon.sfm.mapping._mapping_options`), so a wrong focal
length does not stop it: every image still registers, but the layout bends, tracks break up and
the dense stage later finds almost no point that agrees across views ("the SfM poses may be
wrong"), minutes later and pointing the wrong way. When a capture's cameras.json gives reference
poses, the layout check names the intrinsics (:func:`artrecon.configuration._layout_cause`); plain
image folders have no such reference, so the images must tell. :func:`supported_focal` bundle-
adjusts a copy of the reconstruction with the focal lengths free; :func:`check_given_focal`
refuses the given intrinsics when the images support a clearly different focal length *and* fit
it clearly better.
"""

from __future__ import annotations

import numpy as np
import pycolmap

from artrecon.errors import MismatchError
from artrecon.sfm.config import SfMConfig
from artrecon.sfm.mapping import adjustment_options


def supported_focal(reconstruction: pycolmap.Reconstruction, config: SfMConfig) -> dict:
    """The focal length the images support: bundle adjustment of a copy of ``reconstruction``
    with the focal lengths free (principal point and the rest held); the reconstruction itself
    is not changed.

    Parameters
    ----------
    reconstruction : pycolmap.Reconstruction
        SfM's result with the given intrinsics held fixed (one camera shared by all images).
    config : SfMConfig
        ``num_threads`` for the solver (one: the same figures every run).

    Returns
    -------
    dict
        ``given_fx_px``, ``given_focal_px`` (mean of the camera's fx and fy, as given),
        ``supported_focal_px`` (after the free bundle adjustment), ``ratio`` (given /
        supported), ``reprojection_given_px`` and ``reprojection_free_px`` (mean reprojection
        error before and after).
        Empty when the reconstruction has other than one camera.
    """
    cameras = list(reconstruction.cameras.values())
    if len(cameras) != 1:
        return {}
    copy = pycolmap.Reconstruction(reconstruction)
    options = adjustment_options(config, refine_focal_length=True)
    before = float(reconstruction.compute_mean_reprojection_error())
    pycolmap.bundle_adjustment(copy, options)
    given = float(cameras[0].mean_focal_length())
    supported = float(next(iter(copy.cameras.values())).mean_focal_length())
    return {"given_fx_px": float(cameras[0].focal_length_x), "given_focal_px": given,
            "supported_focal_px": supported,
            "ratio": given / supported, "reprojection_given_px": before,
            "reprojection_free_px": float(copy.compute_mean_reprojection_error())}


def check_given_focal(figures: dict, config: SfMConfig, where: str) -> None:
    """Refuse given intrinsics whose focal length the images contradict (:func:`supported_focal`).

    Both must hold, so that right intrinsics are never blamed: the supported focal length
    differs from the given one by more than ``config.max_focal_mismatch`` (a fraction), and
    freeing it divides the mean reprojection error by at least
    ``config.min_focal_reprojection_gain`` (a focal length that drifts on weak geometry does
    not fit the images much better).

    Raises
    ------
    MismatchError
        With the figures (``agreement``) and a message that names the intrinsics.
    """
    if not figures:
        return
    ratio = figures["ratio"]
    gain = figures["reprojection_given_px"] / max(figures["reprojection_free_px"], 1e-9)
    if abs(np.log(ratio)) <= np.log1p(config.max_focal_mismatch) \
            or gain < config.min_focal_reprojection_gain:
        return
    raise MismatchError(
        f"{where}: the given intrinsics do not fit the images. Likely cause: the intrinsics. "
        f"SfM holds given intrinsics fixed; freed, the images support f ≈ "
        f"{figures['supported_focal_px']:.0f} px (mean reprojection error "
        f"{figures['reprojection_free_px']:.2f} px, against {figures['reprojection_given_px']:.2f}"
        f" px with the given ones), the given fx is {figures['given_fx_px']:.0f} px (ratio "
        f"{ratio:.2f}). Pass the right ones (--intrinsics fx,fy,cx,cy in pixels of these images) "
        "or leave --intrinsics out to self-calibrate", figures)
