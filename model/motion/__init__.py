"""Motion maths and files: rotations, kinematics, skeletons from joint names, BVH, clips, features, mirroring."""
