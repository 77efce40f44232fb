"""nao_skin: artificial skin for the NAO robot (ROS 2)."""
