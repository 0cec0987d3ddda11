"""artrecon: occlusion-aware reconstruction of articulated objects from two image sets.

The library works on any two folders of images; it never imports the simulation harness (`sim`)
and never sees ground truth.
"""

import logging

from artrecon._version import __version__

logging.getLogger(__name__).addHandler(logging.NullHandler())

# The public entry point: artrecon.reconstruct(images_a, images_b, ...) -> ArticulatedModel.
# It shadows the submodule name on purpose.
from artrecon.reconstruct import reconstruct  # noqa: E402

__all__ = ["reconstruct", "__version__"]
