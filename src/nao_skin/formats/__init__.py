"""Files and messages: rosbag2, the thesis' text format, skinManager bottles, outputs."""
