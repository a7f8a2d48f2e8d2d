"""jaxpose: pose of an arbitrary kinematic skeleton from a single depth image."""

__version__ = "0.1.0"
