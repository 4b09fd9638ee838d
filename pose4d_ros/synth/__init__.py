"""The synthetic RGB-D renderer behind `pose4d synth`: people in CAD-60's on-disk format.

- `render`: bodies (capsules and ellipsoids on a Kinect v1 skeleton), retargeting of real motion,
  random textured rooms, and the rendering of one frame;
- `raycast`: the numba ray-casting and shading kernels;
- `kinect`: the Kinect v1 depth model (projector shadows, noise, quantisation, holes);
- `textures`: texture tiles from photographs and procedural fabrics;
- `video`: UTKinect takes to CAD-60 videos on disk.

Like `datasets`, nothing here imports rclpy or a message package.
"""
