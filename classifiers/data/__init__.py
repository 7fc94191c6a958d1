"""Image data: a reader for a user's ``root/<class>/*.png`` folders and a renderer of object classes."""

from classifiers.data.conditions import MISSION, TRAINING, Conditions, get_conditions
from classifiers.data.image_folder import ImageFolder
from classifiers.data.render import (
    FRAME_SHAPE,
    OBJECTS,
    render_images,
    render_sequence,
    write_image_folder,
)

__all__ = [
    "FRAME_SHAPE",
    "MISSION",
    "OBJECTS",
    "TRAINING",
    "Conditions",
    "ImageFolder",
    "get_conditions",
    "render_images",
    "render_sequence",
    "write_image_folder",
]
