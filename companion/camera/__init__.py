"""Real stereo camera input: calibration and rectification, frame sources, the publisher.

* :mod:`companion.camera.calibration`: load an OpenCV stereo calibration, rectify pairs.
* :mod:`companion.camera.sources`: V4L2 pair, side-by-side UVC camera, folder replay.
* ``python -m companion.camera`` (``stereo-camera``): publish frames on
  ``stereo_avoid/<vehicle_id>/stereo`` in the :mod:`protocols.stereo_frame` format.
"""
