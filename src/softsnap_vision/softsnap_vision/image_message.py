"""sensor_msgs/Image fields -> a BGR numpy image, with every check a bad message needs.

No rclpy and no cv_bridge (not on PyPI): works on any object with the Image fields
(``height``, ``width``, ``encoding``, ``step``, ``data``). Colour encodings only: the
markers are told apart by colour. The image is converted once, here.
"""
from __future__ import annotations

import cv2
import numpy as np

__all__ = ['ImageMessageError', 'image_to_bgr', 'COLOR_ENCODINGS']

#: Encodings we read, their channel count and the conversion to BGR (None: already BGR).
COLOR_ENCODINGS = {
    'bgr8': (3, None),
    'rgb8': (3, cv2.COLOR_RGB2BGR),
    'bgra8': (4, cv2.COLOR_BGRA2BGR),
    'rgba8': (4, cv2.COLOR_RGBA2BGR),
}


class ImageMessageError(ValueError):
    """The image message cannot be used (encoding, size, data length); says why."""


def image_to_bgr(msg, expected_size: tuple[int, int] | None = None) -> np.ndarray:
    """BGR uint8 array (height, width, 3) of an Image message.

    ``expected_size`` (width, height), e.g. the camera_info's, must match.
    """
    encoding = str(msg.encoding).lower()
    if encoding not in COLOR_ENCODINGS:
        raise ImageMessageError(f'encoding {msg.encoding!r} not supported (colour images only: '
                                f'{", ".join(COLOR_ENCODINGS)})')
    channels, conversion = COLOR_ENCODINGS[encoding]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    if h <= 0 or w <= 0:
        raise ImageMessageError(f'empty image ({w}x{h} px)')
    if expected_size is not None and (w, h) != tuple(expected_size):
        raise ImageMessageError(f'image is {w}x{h} px but the camera_info is for '
                                f'{expected_size[0]}x{expected_size[1]}')
    if step < w * channels:
        raise ImageMessageError(f'step {step} B is below width x channels ({w * channels} B)')
    data = np.frombuffer(msg.data, dtype=np.uint8)
    if data.size < step * h:
        raise ImageMessageError(f'{data.size} B of data for {h} rows of {step} B')
    rows = data[:step * h].reshape(h, step)[:, :w * channels].reshape(h, w, channels)
    if conversion is None:
        return rows
    return cv2.cvtColor(rows, conversion)
