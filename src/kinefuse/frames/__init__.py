"""What a sensor delivers: one body-tracker frame (``BodyFrame``), a stream of them in batch form
(``BodyFrames``, NaN + mask), the calibration phase's depth images (``DepthFrame``).

The one observation type every layer above shares (fusion, the store, the live client). May
import only errors, skeleton, geometry and camera."""
