"""Full ``ros2msg`` schema text, laid out exactly as rosbag2 writes it into MCAP schemas.

rosbag2 (rosbag2_cpp LocalMessageDefinitionSource) appends, depth first and each type once, every
non-primitive field type of the .msg text, in sorted order, each as::

    '\\n' + '=' * 80 + '\\n' + 'MSG: pkg/Type\\n' + <text of pkg/Type and its own dependencies>

The dependency names are written as they appear in the .msg file ('std_msgs/Header'), with
same-package types qualified by the package ('geometry_msgs/Vector3').
"""
import functools
import re

from mantis_rig.recording.message_types import msg_file_text, split_type_name

SCHEMA_ENCODING = 'ros2msg'
DELIMITER = '=' * 80 + '\n'
_MSG_FIELD_TYPE_RE = re.compile(r'(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+')
_PRIMITIVE_TYPES = frozenset({
    'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16',
    'int32', 'uint32', 'int64', 'uint64', 'string'})
_MAX_DEPTH = 50


def msg_dependencies(text, package):
    """Sorted non-primitive field types named in a .msg text, qualified by package."""
    found = set()
    for match in _MSG_FIELD_TYPE_RE.finditer(text):
        field_type = match.group(1)
        if field_type in _PRIMITIVE_TYPES:
            continue
        found.add(field_type if '/' in field_type else f'{package}/{field_type}')
    return sorted(found)


@functools.cache
def full_message_definition(type_name):
    """The type's .msg text followed by every dependency's, rosbag2-style."""
    seen = set()

    def append_recursive(name, depth):
        if depth <= 0:
            raise RecursionError(f'message definition of {type_name} nests too deeply')
        text = msg_file_text(name)
        package, _ = split_type_name(name)
        for dependency in msg_dependencies(text, package):
            if dependency not in seen:
                seen.add(dependency)
                text += '\n' + DELIMITER + f'MSG: {dependency}\n'
                text += append_recursive(dependency, depth - 1)
        return text

    return append_recursive(type_name, _MAX_DEPTH)
