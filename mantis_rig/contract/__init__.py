"""The rig's ROS contract, declared once, in three parts: its names and QoS (`ros_names`), its
nodes' parameters (`node_parameters`) and the document generated from both
(`interfaces_document`: ``docs/ros_interfaces.md``'s section, ``python -m mantis_rig.contract``).
Everything else takes its names from here, as ``contract.NAME`` or from the part.

The contract stands on the devices' layer and the simulator alone (docs/architecture.md).
"""
from .interfaces_document import *  # noqa: F401,F403
from .interfaces_document import __all__ as _document
from .node_parameters import *  # noqa: F401,F403
from .node_parameters import __all__ as _parameters
from .ros_names import *  # noqa: F401,F403
from .ros_names import __all__ as _names

__all__ = [*_names, *_parameters, *_document]
