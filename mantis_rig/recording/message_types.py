"""Find ROS 2 message types: class <-> name, .msg text, type hash.

Works on a sourced ROS 2 install (``AMENT_PREFIX_PATH`` + ament_index_python) and in this
repository's PyPI virtualenv, whose interface packages live under ``sys.prefix/share``.
"""
import functools
import importlib
import json
import os
from pathlib import Path
import re
import sys

try:  # real ROS installs ship it; the PyPI rclpy wheels do not
    from rosidl_runtime_py.utilities import get_message as _rosidl_get_message
except ImportError:  # pragma: no cover - depends on the environment
    _rosidl_get_message = None

# pkg/Type or pkg/msg/Type
_TYPE_NAME_RE = re.compile(r'^([A-Za-z][A-Za-z0-9_]*)/(?:(msg)/)?([A-Za-z][A-Za-z0-9_]*)$')


class MessageTypeError(LookupError):
    """A message type name could not be resolved to a class or a definition."""


def split_type_name(type_name):
    """'geometry_msgs/msg/Wrench' or 'geometry_msgs/Wrench' -> ('geometry_msgs', 'Wrench')."""
    match = _TYPE_NAME_RE.match(type_name)
    if not match:
        raise MessageTypeError(f'not a ROS 2 message type name: {type_name!r}')
    return match.group(1), match.group(3)


def type_name_of(msg_or_class):
    """'pkg/msg/Type' of a generated message instance or class."""
    cls = msg_or_class if isinstance(msg_or_class, type) else type(msg_or_class)
    package = cls.__module__.split('.')[0]
    if not hasattr(cls, 'get_fields_and_field_types'):
        raise MessageTypeError(f'{cls.__module__}.{cls.__name__} is not a ROS 2 message class')
    return f'{package}/msg/{cls.__name__}'


@functools.cache
def message_class(type_name):
    """The generated Python class for 'pkg/msg/Type'."""
    package, name = split_type_name(type_name)
    if _rosidl_get_message is not None:
        try:
            return _rosidl_get_message(f'{package}/msg/{name}')
        except (AttributeError, ModuleNotFoundError, ValueError):
            pass
    try:
        return getattr(importlib.import_module(f'{package}.msg'), name)
    except (ImportError, AttributeError) as exc:
        raise MessageTypeError(f'cannot import message class {package}.msg.{name}: {exc}') from exc


def _prefix_candidates():
    for entry in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep):
        if entry:
            yield Path(entry)
    yield Path(sys.prefix)


@functools.cache
def package_share_dir(package):
    """share/<package> via ament_index_python, else the ament index under sys.prefix."""
    try:
        from ament_index_python.packages import get_package_share_directory
        return Path(get_package_share_directory(package))
    except (ImportError, LookupError, OSError, ValueError):
        pass  # no AMENT_PREFIX_PATH (plain virtualenv) or package not on it
    for prefix in _prefix_candidates():
        marker = prefix / 'share' / 'ament_index' / 'resource_index' / 'packages' / package
        if marker.exists():
            return prefix / 'share' / package
    raise MessageTypeError(f'package {package!r} not found in the ament index '
                           f'(AMENT_PREFIX_PATH or {sys.prefix})')


def msg_file_text(type_name):
    """Contents of the type's installed .msg file."""
    package, name = split_type_name(type_name)
    path = package_share_dir(package) / 'msg' / f'{name}.msg'
    try:
        return path.read_text(encoding='utf-8')
    except OSError as exc:
        raise MessageTypeError(f'no .msg definition for {type_name}: {exc}') from exc


def type_description_hash(type_name):
    """RIHS01_... hash from the installed type description JSON, '' if not installed."""
    package, name = split_type_name(type_name)
    try:
        path = package_share_dir(package) / 'msg' / f'{name}.json'
        hashes = json.loads(path.read_text(encoding='utf-8'))['type_hashes']
    except (MessageTypeError, OSError, ValueError, KeyError):
        return ''
    wanted = f'{package}/msg/{name}'
    return next((h['hash_string'] for h in hashes if h.get('type_name') == wanted), '')
