"""The two LeRobot policies, each in LeRobot's own layout (configuration_/modeling_/processor_<type>.py),
and the point-cloud processor steps they share."""
