"""Importers: ROS1/ROS2 bags (rosbags), rostopic-echo CSV logs and image-frame folders
into PoseidonSLAM recordings (:mod:`missions.importers.cli` is ``poseidon import``)."""
