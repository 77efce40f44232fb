"""nao_skin: self-touch calibration of the artificial skin on the Nao (ROS 2)."""
