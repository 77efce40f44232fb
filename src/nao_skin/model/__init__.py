"""Robot and skin as data: kinematics, skin parts and calibrations, taxel files, layouts, URDF."""
