"""pose4d_ros: live RGB-D human pose tracking after the 4D deformable part model."""

__version__ = '0.1.0'
