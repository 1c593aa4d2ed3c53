"""A tiny block-style YAML emitter that lays documents out the way yaml-cpp (rosbag2) does.

Only dicts, lists, str, int, bool and None are needed for rosbag2 metadata. Key order is kept.
Strings that would not survive as plain scalars are written double-quoted (JSON escaping, which is
valid YAML); empty strings as ``""``, empty maps as ``~`` (yaml-cpp's null), empty lists as ``[]``.
"""
import json
import re

_PLAIN_SAFE = re.compile(r'^[A-Za-z0-9_/][A-Za-z0-9_./\-]*$')
_YAML_SPECIAL_WORDS = frozenset({
    'true', 'false', 'yes', 'no', 'on', 'off', 'null', 'y', 'n', '~'})
_INDENT = '  '


def _scalar(value):
    if value is None:
        return '~'
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value)
    text = str(value)
    looks_numeric = re.match(r'^[-+.]?\d', text) is not None
    if (_PLAIN_SAFE.match(text) and not looks_numeric
            and text.lower() not in _YAML_SPECIAL_WORDS):
        return text
    return json.dumps(text)


def _is_collection(value):
    return isinstance(value, (dict, list)) and len(value) > 0


def _empty(value):
    return '~' if isinstance(value, dict) else '[]'


def _emit_map(mapping, indent, lines, first_prefix=None):
    for index, (key, value) in enumerate(mapping.items()):
        prefix = first_prefix if (index == 0 and first_prefix is not None) else indent
        if _is_collection(value):
            lines.append(f'{prefix}{key}:')
            _emit_value(value, indent + _INDENT, lines)
        elif isinstance(value, (dict, list)):
            lines.append(f'{prefix}{key}: {_empty(value)}')
        else:
            lines.append(f'{prefix}{key}: {_scalar(value)}')


def _emit_list(items, indent, lines):
    for item in items:
        if isinstance(item, dict) and item:
            _emit_map(item, indent + _INDENT, lines, first_prefix=f'{indent}- ')
        elif isinstance(item, list) and item:
            lines.append(f'{indent}-')
            _emit_list(item, indent + _INDENT, lines)
        elif isinstance(item, (dict, list)):
            lines.append(f'{indent}- {_empty(item)}')
        else:
            lines.append(f'{indent}- {_scalar(item)}')


def _emit_value(value, indent, lines):
    if isinstance(value, dict):
        _emit_map(value, indent, lines)
    else:
        _emit_list(value, indent, lines)


def emit_yaml(document):
    """Block-style YAML text for a dict or list document, ending with a newline."""
    lines = []
    if isinstance(document, (dict, list)) and document:
        _emit_value(document, '', lines)
    else:
        lines.append(_empty(document) if isinstance(document, (dict, list))
                     else _scalar(document))
    return '\n'.join(lines) + '\n'
