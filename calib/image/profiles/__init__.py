"""Find the direct spot and the first-order band in an HDR image, and extract RGB profiles from them.

The rig's camera sees the slit twice: the direct (0th-order) image, a bright compact spot, and the
first-order rainbow, a long band that starts some distance from the spot and runs away from it along
the dispersion direction. :func:`detect_geometry` finds both automatically, at any angle:

1. the spot is the brightest feature; its centre is the intensity-weighted centroid (sub-pixel);
2. bands are the significant regions outside the spot; the one with most flux is the first order, and
   a region on the opposite side is the other first order (both are reported; the stronger is
   ``side = +1``, unless it runs off the frame and the other is whole: the other is then read);
3. the direction is refined by fitting a line to the band's across-centroids, then the band's
   extent along (where its signal exceeds ``extent_fraction`` of its maximum, plus a margin, cut
   before a 2nd order) and across (its half-maximum width) is measured.

All coordinates are sensor pixels of the visible raw area: ``x`` is the column, ``y`` the row, the
dispersion angle is measured from +x towards +y. For a point, ``u`` is its distance from the spot's
centre along an order's direction and ``v`` its distance across (positive to the right of the
direction of travel on screen).

:func:`extract` applies one geometry to an image: the direct RGB is the sum of the background-subtracted
radiance over the spot's aperture (times the plane pitch squared: DN/s integrated over sensor pixels);
the diffracted profile is the mean across the central part of the band in bins of ``bin_px`` along
it, with every channel's samples placed at their true sensor position and resampled to one common
``pixel`` axis (distance from the spot centre, increasing away from it). Standard deviations are
propagated from the HDR variance. One geometry, detected on the brightest (broadband) lamp, is meant
to be applied to every lamp of a capture so that all profiles share their pixel axis.

References
----------
Makabe, L., Santo, H., Okura, F., Brown, M. S., Matsushita, Y. (2025). Spectral Sensitivity Estimation
with an Uncalibrated Diffraction Grating. §4.2: the band is cropped ~200 px across and averaged to 1-D.
"""

from calib.image.profiles.detection import detect_geometry
from calib.image.profiles.diagnostics import write_geometry_png
from calib.image.profiles.extraction import Extraction, extract
from calib.image.profiles.geometry import (
    GEOMETRY_FORMAT_VERSION,
    DetectionError,
    DiffractionGeometry,
    OrderBand,
    Side,
)

__all__ = [
    "GEOMETRY_FORMAT_VERSION",
    "DetectionError",
    "DiffractionGeometry",
    "Extraction",
    "OrderBand",
    "Side",
    "detect_geometry",
    "extract",
    "write_geometry_png",
]
