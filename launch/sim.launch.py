"""Launch the tensegrity_sim node with config/sim_node.yaml (installed under share/tensegrity_sim).

    ros2 launch tensegrity_sim sim.launch.py scene:=icosahedron real_time_factor:=2.0
    ros2 launch tensegrity_sim sim.launch.py params_file:=my_params.yaml
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare


def generate_launch_description():
    params_file = PathJoinSubstitution([FindPackageShare("tensegrity_sim"), "config", "sim_node.yaml"])
    return LaunchDescription([
        DeclareLaunchArgument("params_file", default_value=params_file,
                              description="parameters of the node (YAML, see msg_docs/parameters.md)"),
        DeclareLaunchArgument("scene", default_value="prism3",
                              description="built-in scene name or path to a scene YAML file"),
        DeclareLaunchArgument("real_time_factor", default_value="1.0",
                              description="simulated s per wall-clock s; 0 = as fast as possible"),
        Node(
            package="tensegrity_sim",
            executable="sim_node",
            name="tensegrity_sim",
            output="screen",
            # later entries override earlier ones: the file, then the launch arguments
            parameters=[LaunchConfiguration("params_file"),
                        {"scene": LaunchConfiguration("scene"),
                         "real_time_factor": LaunchConfiguration("real_time_factor")}],
        ),
    ])
