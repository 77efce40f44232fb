"""``ros2 launch PACKAGE FILE [name:=value ...]`` as ros2launch runs it, for a machine without ros2cli (not on
PyPI): the launch file from the package's share directory, included with the arguments into a
``LaunchService`` of the real ``launch`` package, which handles Ctrl-C and returns the exit code."""
import sys
from pathlib import Path

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription, LaunchService
from launch.actions import IncludeLaunchDescription
from launch.launch_description_sources import AnyLaunchDescriptionSource


def main(argv) -> int:
    package, file_name, *arguments = argv
    found = sorted(Path(get_package_share_directory(package)).rglob(file_name))
    if not found:
        print(f"file '{file_name}' was not found in the share directory of package '{package}'", file=sys.stderr)
        return 1
    service = LaunchService(argv=arguments, noninteractive=True)
    service.include_launch_description(LaunchDescription([IncludeLaunchDescription(
        AnyLaunchDescriptionSource(str(found[0])),
        launch_arguments=[tuple(a.split(":=", 1)) for a in arguments])]))
    return service.run()


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
