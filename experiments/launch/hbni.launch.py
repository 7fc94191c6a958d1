"""Launch the HBNI live node (``hbni-ros-node``): camera images in, macro-observations and decisions out.

    ros2 launch $(hbni-ros-node --launch-file) classifier:=/path/classifier.safetensors \\
        posterior:=/path/posterior.safetensors [controller:=...] [namespace:=/robot1] [image:=/front/image_raw] \\
        [use_sim_time:=true] [threshold:=0.9] ...

Every node parameter (:data:`experiments.launch.PARAMETERS`) is a launch argument with the node's default, and so
are ``namespace`` (the node's), ``image`` (the camera topic ``camera/image_raw`` is remapped to, and its
``/compressed`` subtopic) and ``use_sim_time``. ``ros2 launch ... --show-args`` lists them.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

from experiments.launch import EXECUTABLE, IMAGE_TOPIC, NODE_NAME, PARAMETERS

TYPES = {"string": str, "double": float, "integer": int, "bool": bool}


def generate_launch_description() -> LaunchDescription:
    arguments = [
        DeclareLaunchArgument(
            p.name,
            default_value=str(p.default).lower() if p.kind == "bool" else str(p.default),
            description=p.description,
        )
        for p in PARAMETERS
    ]
    arguments += [
        DeclareLaunchArgument("namespace", default_value="", description="the node's namespace ('': the root)"),
        DeclareLaunchArgument("image", default_value=IMAGE_TOPIC, description="the camera's image topic"),
        DeclareLaunchArgument("use_sim_time", default_value="false", description="use the simulation's /clock"),
    ]
    values = {p.name: ParameterValue(LaunchConfiguration(p.name), value_type=TYPES[p.kind]) for p in PARAMETERS}
    values["use_sim_time"] = ParameterValue(LaunchConfiguration("use_sim_time"), value_type=bool)
    node = Node(
        executable=EXECUTABLE,
        name=NODE_NAME,
        namespace=LaunchConfiguration("namespace"),
        parameters=[values],
        remappings=[
            (IMAGE_TOPIC, LaunchConfiguration("image")),
            (f"{IMAGE_TOPIC}/compressed", [LaunchConfiguration("image"), "/compressed"]),
        ],
        output="screen",
    )
    return LaunchDescription([*arguments, node])
