"""The ROS contract (mantis_rig/contract/): declared once, documented from itself, and the only
place in mantis_rig where a ROS name is written out.

No DDS here: the source is read with `ast`, the synthetic bags are written and read as files."""
import ast
from pathlib import Path
import re

import pytest
from rclpy.qos import DurabilityPolicy, ReliabilityPolicy

from mantis_rig import contract
from mantis_rig.analysis.inputs.bag import read_trial_bag
from mantis_rig.hardware.apt_units import Z8_COUNTS_PER_MM
from mantis_rig.hardware.device_interfaces import StageLimits
from mantis_rig.recording import BagReader
from mantis_rig.recording.trial_summary import summarize
from mantis_rig.replay.replay_qos import replay_qos
from mantis_rig.replay.synthetic import write_synthetic_trial
from mantis_rig.stack.node_table import DEVICES, NODES

REPO = Path(__file__).resolve().parents[2]
PACKAGE = REPO / 'mantis_rig'
CONTRACT = PACKAGE / 'contract'
DOC = REPO / 'docs' / 'ros_interfaces.md'

# a ROS topic / service name: lower-case segments joined by '/', with a leading '/' or with
# at least two segments (std_msgs/msg/Float64 has capitals; a file path has a '.')
ROS_NAME = re.compile(r'/[a-z_][a-z0-9_]*(/[a-z_][a-z0-9_]*)*/?|'
                      r'[a-z_][a-z0-9_]*(/[a-z_][a-z0-9_]*)+/?')


def contract_names() -> set:
    """The names only the contract may spell: topics, services (relative and as they resolve
    in the root namespace), node names, and the force ceiling's parameter."""
    names = set()
    for item in (*contract.TOPICS, *contract.SERVICES):
        # a one-word relative name ('clock', 'diagnostics') is also an ordinary word (the
        # replay node's parameter `clock`): only its resolved form counts
        names |= {item.name, contract.resolve(item)} if '/' in item.name \
            else {contract.resolve(item)}
    names |= {*contract.RIG_NODES, contract.SIM_RIG_PROCESS, *contract.TOOL_NODES,
              contract.FORCE_CEILING.name}
    return names


#: string pieces that look like ROS names and are not: (file, text) -> what they are
NOT_ROS_NAMES = {
    ('mantis_rig/hardware/nidaq.py', '/line'): 'part of a DAQ line name, Dev1/port0/line0',
    ('mantis_rig/recording/message_types.py', '/msg/'): 'part of a message type, pkg/msg/Type',
    ('mantis_rig/analysis/intervals.py', 'm/s'): 'a unit, metres per second',
    ('mantis_rig/runtime/process_state.py', '/proc'): 'a path, /proc',
}


def _docstrings(tree) -> set:
    """ids of the string constants that are docstrings (prose, not names in use)."""
    ids = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                ids.add(id(body[0].value))
    return ids


def quoted_ros_names(path: Path) -> list:
    """'file:line: text' of every string constant in ``path`` (f-string parts included,
    docstrings not) that is a contract name or looks like a ROS name."""
    tree = ast.parse(path.read_text(encoding='utf-8'), str(path))
    names, skip = contract_names(), _docstrings(tree)
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) \
                and id(node) not in skip:
            text = node.value
            if (str(path.relative_to(REPO)), text) in NOT_ROS_NAMES:
                continue
            if text in names or ROS_NAME.fullmatch(text):
                found.append(f'{path.relative_to(REPO)}:{node.lineno}: {text!r}')
    return found


def test_no_ros_name_is_written_out_in_mantis_rig_outside_the_contract():
    found = [hit for path in sorted(PACKAGE.rglob('*.py')) if CONTRACT not in path.parents
             for hit in quoted_ros_names(path)]
    assert found == []


def test_the_scan_finds_what_it_looks_for(tmp_path):
    sample = tmp_path / 'sample.py'
    sample.write_text('"""Docstrings may say /stage/joint_state."""\n'
                      "A = '/loadcell/force_block'\n"
                      "B = 'stage/home'\n"
                      "C = f'/{A}/get_state'\n"
                      "D = 'force_ceiling_n'\n"
                      "E = 'stage_node'\n"
                      "F = 'std_msgs/msg/Float64'\n"
                      "G = 'config/foxglove/trial_layout.json'\n")
    original = REPO
    hits = [h.split(': ', 1)[1] for h in quoted_ros_names_at(sample, tmp_path)]
    assert hits == ["'/loadcell/force_block'", "'stage/home'", "'/get_state'",
                    "'force_ceiling_n'", "'stage_node'"]
    assert original == REPO


def quoted_ros_names_at(path, root):
    global REPO
    saved, REPO = REPO, root
    try:
        return sorted(quoted_ros_names(path), key=lambda h: int(h.split(':')[1]))
    finally:
        REPO = saved


def test_the_launch_file_takes_its_names_from_the_contract():
    assert quoted_ros_names_at(REPO / 'launch' / 'mantis_rig.launch.py', REPO) == []


# ----------------------------------------------------------------------------- the document
def test_the_document_holds_the_contract_as_generated():
    text = DOC.read_text(encoding='utf-8')
    section = contract.document_section(text)
    assert section is not None, f'{DOC} has no generated section'
    assert section == contract.markdown(), (
        f'{DOC} differs from the contract: run `python -m mantis_rig.contract {DOC}`')


def test_the_document_lists_every_topic_service_and_parameter_with_type_and_unit():
    section = contract.document_section(DOC.read_text(encoding='utf-8'))
    rows = {tuple(cell.strip() for cell in line.strip('|').split('|'))
            for line in section.splitlines() if line.startswith('| `')}
    for topic in contract.TOPICS:
        assert any(r[:2] == (f'`{topic.name}`', f'`{topic.type_name}`') for r in rows), topic
    for service in contract.SERVICES:
        assert any(r[:2] == (f'`{service.name}`', f'`{service.type_name}`') for r in rows)
    for node, specs in contract.NODE_PARAMETERS.items():
        for spec in specs:
            assert any(r[0] == f'`{node}`' and r[1].split()[0] == f'`{spec.name}`'
                       and r[2] == spec.type_name and r[4] == spec.unit for r in rows), \
                (node, spec.name)


def test_every_ros_name_the_document_mentions_is_the_contracts():
    """Outside the generated section too: a name written in the prose (as it resolves in the
    root namespace) is a contract topic or service, or a node's standard interface."""
    text = DOC.read_text(encoding='utf-8')
    known = {contract.resolve(x) for x in (*contract.TOPICS, *contract.SERVICES)}
    standard = (contract.GET_STATE, contract.CHANGE_STATE, contract.SET_PARAMETERS,
                contract.SET_PARAMETERS_ATOMICALLY,
                contract.TRANSITION_EVENT)
    known |= {contract.resolve(contract.node_interface(n, s))
              for n in ('<node>', *contract.RIG_NODES) for s in standard}
    mentioned = set(re.findall(r'`(/[a-z_<>]+(?:/[a-z_<>]+)+)`', text))
    mentioned |= {m for m in re.findall(r'`(/[a-z_]+)`', text)}
    namespaced = {m for m in mentioned if m.startswith('/rig2/')}
    unknown = {m for m in mentioned - namespaced if m not in known} - {'/', '/rig2'}
    assert unknown == set()


# ----------------------------------------------------------------------------- declarations
def test_names_are_relative_and_declared_once():
    names = [t.name for t in contract.TOPICS] + [s.name for s in contract.SERVICES]
    assert len(names) == len(set(names))
    assert not any(name.startswith('/') for name in names)
    assert tuple(entry.name for entry in DEVICES) == contract.DEVICE_NODES
    assert tuple(entry.name for entry in NODES) == contract.RIG_NODES
    for specs in contract.NODE_PARAMETERS.values():
        assert len({s.name for s in specs}) == len(specs)


def test_every_qos_kind_is_reliable_and_publishers_match_subscribers():
    for topic in contract.TOPICS:
        offered, asked = topic.qos.publisher(), topic.qos.subscriber()
        assert offered.reliability == asked.reliability == ReliabilityPolicy.RELIABLE
        assert offered.durability == asked.durability
    assert contract.SUPERVISOR_STATE.qos.publisher().durability == \
        DurabilityPolicy.TRANSIENT_LOCAL
    assert contract.SUPERVISOR_STATE.qos.publisher().depth == 1


def test_the_parameters_agree_with_the_drivers():
    limits = StageLimits()
    assert contract.STAGE_MAX_SPEED_M_PER_S == limits.max_speed_m_per_s
    assert contract.STAGE_TRAVEL_M == (limits.min_position_m, limits.max_position_m)
    counts = next(s for s in contract.STAGE_PARAMETERS if s.name == 'counts_per_mm')
    assert counts.default == Z8_COUNTS_PER_MM
    guards = [s for node in contract.FORCE_GUARD_NODES
              for s in contract.NODE_PARAMETERS[node] if s.name == contract.FORCE_CEILING.name]
    assert len(guards) == len(contract.FORCE_GUARD_NODES)
    assert all((g.default, g.range, g.unit) == (contract.FORCE_CEILING.default,
                                                contract.FORCE_CEILING.range, 'N')
               for g in guards)


def test_the_nodes_declare_the_contracts_parameters():
    from mantis_rig.nodes import camera_node, loadcell_node, stage_node
    from mantis_rig.nodes.device_node import COMMON_PARAMETERS
    from mantis_rig.simulated import sim_world_node
    from mantis_rig.trial.supervisor_settings import PARAMETERS
    assert COMMON_PARAMETERS == contract.DEVICE_COMMON_PARAMETERS
    assert stage_node.StageNode.PARAMETERS == contract.STAGE_PARAMETERS
    assert loadcell_node.LoadcellNode.PARAMETERS == contract.LOADCELL_PARAMETERS
    assert camera_node.CameraNode.PARAMETERS == contract.CAMERA_PARAMETERS
    assert sim_world_node.PARAMETERS == contract.WORLD_PARAMETERS
    assert tuple(PARAMETERS.values()) == contract.SUPERVISOR_PARAMETERS


# ----------------------------------------------------------------------------- namespaces
def test_names_resolve_in_a_namespace_and_back():
    assert contract.resolve(contract.FORCE_BLOCK) == '/loadcell/force_block'
    assert contract.resolve(contract.FORCE_BLOCK, '/rig2') == '/rig2/loadcell/force_block'
    assert contract.resolve(contract.FORCE_BLOCK, 'rig2/') == '/rig2/loadcell/force_block'
    assert contract.relative('/rig2/loadcell/force_block', '/rig2') == 'loadcell/force_block'
    with pytest.raises(ValueError):
        contract.relative('/rig1/loadcell/force_block', '/rig2')
    with pytest.raises(ValueError):
        contract.resolve('/loadcell/force_block')
    assert contract.bag_namespace(['/rig2/camera/markers', '/rig2/diagnostics']) == '/rig2'
    assert contract.bag_namespace(['/camera/markers', '/diagnostics']) == '/'
    assert contract.bag_namespace(['/other']) == '/'
    assert contract.find_topic('/a/b/supervisor/state') is contract.SUPERVISOR_STATE
    assert contract.find_topic('/x/markers') is None


def test_a_bag_recorded_in_a_namespace_is_analysed_as_the_same_bag_at_the_root(tmp_path):
    write_synthetic_trial(tmp_path / 'root')
    write_synthetic_trial(tmp_path / 'rig2', namespace='/rig2')
    assert set(BagReader(tmp_path / 'rig2').topics) == {
        '/rig2/' + t.name for t in (contract.JOINT_STATE, contract.FORCE_BLOCK, contract.WRENCH,
                                    contract.TRIGGER_TIME, contract.MARKERS,
                                    contract.SUPERVISOR_STATE, contract.DIAGNOSTICS)}
    root, rig2 = summarize(tmp_path / 'root'), summarize(tmp_path / 'rig2')
    assert (root.namespace, rig2.namespace) == ('/', '/rig2')
    for field in ('force_samples', 'force_rate_hz', 'peak_force_n', 'trigger_s',
                  'marker_span_s', 'marker_frames'):
        assert getattr(root, field) == getattr(rig2, field), field
    assert [s for s, _ in root.states] == [s for s, _ in rig2.states]
    a, b = read_trial_bag(tmp_path / 'root'), read_trial_bag(tmp_path / 'rig2')
    assert (a.tracks.time_s == b.tracks.time_s).all()
    assert (a.force_N == b.force_N).all()


def test_the_synthetic_bag_offers_the_contracts_qos(tmp_path):
    """No best-effort publisher, not even in a synthetic bag; the latched state stays latched
    when replayed from whatever namespace."""
    write_synthetic_trial(tmp_path / 'rig2', namespace='/rig2')
    from mantis_rig.recording.offered_qos import parse_offered_qos_string
    reader = BagReader(tmp_path / 'rig2')
    for name, info in reader.topics.items():
        offered = parse_offered_qos_string(info.metadata.get('offered_qos_profiles', ''))
        assert [o['reliability'] for o in offered] == ['reliable'], name
        replayed = replay_qos(name, offered)
        latched = contract.find_topic(name).qos.transient_local
        assert (replayed.durability == DurabilityPolicy.TRANSIENT_LOCAL) == latched, name


def test_a_heartbeat_names_its_process_so_one_in_the_same_process_is_not_watched():
    source = contract.heartbeat_source('supervisor_node', 4321)
    assert contract.heartbeat_source_pid(source) == 4321
    assert contract.heartbeat_source_pid('supervisor_node') is None      # an older supervisor
