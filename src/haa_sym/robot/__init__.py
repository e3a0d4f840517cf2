"""The robot you already have (issue 25): its description in (URDF/MJCF: the port body's inertia
and gravity stiffness over the leg's configurations), and what the tool found out to the robot's
world (a MuJoCo model running the analysed controller; ros2_control parameters and the certified
region as C). Above ``design/`` (it exports schedules and regions), below ``explore/``."""
