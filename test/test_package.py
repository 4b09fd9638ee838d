"""The installed package: `ros2 run` layout, ament index, config files, the pose4d command."""

from __future__ import annotations

import ast
import graphlib
import importlib
import inspect
import os
import subprocess
import sys
from importlib.metadata import distribution
from pathlib import Path

import pytest
import yaml
from conftest import REPO
from harness import PACKAGE, executable

CONSOLE_SCRIPTS = sorted(ep.name for ep in distribution(PACKAGE).entry_points
                         if ep.group == 'console_scripts')
# every node executable with parameters of its own (`composed` runs four of them, with theirs)
NODE_MODULES = {ep.name: ep.value.split(':')[0] for ep in distribution(PACKAGE).entry_points
                if ep.group == 'console_scripts' and '.nodes.' in ep.value
                and ep.name != 'composed'}


def test_package_found_through_ament_index():
    from ament_index_python.packages import get_package_prefix, get_package_share_directory

    prefix = Path(get_package_prefix(PACKAGE))
    share = Path(get_package_share_directory(PACKAGE))
    assert (prefix / 'share' / 'ament_index' / 'resource_index' / 'packages' / PACKAGE).is_file()
    assert (share / 'package.xml').is_file()
    for cfg in sorted((REPO / 'config').iterdir()):  # the nodes' YAML, DDS profile, RViz set-up
        assert (share / 'config' / cfg.name).read_text() == cfg.read_text(), \
            f'installed {cfg.name} is stale: run make setup'


@pytest.mark.parametrize('name', CONSOLE_SCRIPTS)
def test_executable_where_ros2_run_looks(name):
    path = executable(name)
    assert path.is_file(), f'{path} missing'
    assert os.access(path, os.X_OK), f'{path} is not executable'


def test_pose4d_msgs_is_an_interface_package():
    from ament_index_python import get_resource

    content, _ = get_resource('rosidl_interfaces', 'pose4d_msgs')
    assert 'msg/Joint.msg' in content and 'msg/JointArray.msg' in content
    assert get_resource('packages', 'pose4d_msgs')


def test_tf2_msgs_is_the_standard_interface():
    """/tf's TFMessage, the environment's or built by `make setup` from ros_wheels/tf2_msgs:
    its type hash is ROS 2 Jazzy's, so it speaks with any ROS install's tf2_msgs."""
    import json

    from ament_index_python.packages import get_package_share_directory
    from geometry_msgs.msg import TransformStamped
    from rclpy.serialization import deserialize_message, serialize_message
    from rosbags.typesys import Stores, get_typestore
    from tf2_msgs.msg import TFMessage

    share = Path(get_package_share_directory('tf2_msgs'))
    hashes = json.loads((share / 'msg' / 'TFMessage.json').read_text())['type_hashes']
    ours = {h['type_name']: h['hash_string'] for h in hashes}['tf2_msgs/msg/TFMessage']
    assert ours == get_typestore(Stores.ROS2_JAZZY).hash_rihs01('tf2_msgs/msg/TFMessage')
    msg = TFMessage(transforms=[TransformStamped(child_frame_id='pose4d/1/head')])
    msg.transforms[0].transform.translation.z = 2.5
    assert deserialize_message(serialize_message(msg), TFMessage) == msg


def test_pose4d_command_help_and_version():
    out = subprocess.run([str(executable('pose4d')), '--version'], capture_output=True,
                         text=True, check=True)
    from pose4d_ros import __version__

    assert out.stdout.strip() == f'pose4d {__version__}'
    out = subprocess.run([str(executable('pose4d')), '--help'], capture_output=True, text=True,
                         check=True)
    assert 'usage: pose4d' in out.stdout


def test_pose4d_unknown_verb_fails():
    out = subprocess.run([str(executable('pose4d')), 'no-such-verb'], capture_output=True,
                         text=True)
    assert out.returncode != 0 and 'invalid choice' in out.stderr


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name.split('.')[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split('.')[0])
    return names


ROS_MODULES = {'rclpy', 'rosidl_runtime_py', 'rosbag2_py', 'ament_index_python'}


def _is_ros(module: str) -> bool:
    return module in ROS_MODULES or module.endswith('_msgs') or module.endswith('_interfaces')


@pytest.mark.parametrize('folder', ['core', 'datasets', 'synth', 'wire'])
def test_core_datasets_synth_wire_never_import_ros(folder):
    files = sorted((REPO / PACKAGE / folder).rglob('*.py'))
    assert files
    offenders = {}
    for f in files:
        bad = {m for m in _imports(f) if _is_ros(m)}
        if folder != 'datasets' or f.name != 'bag.py':
            bad |= {m for m in _imports(f) if m == 'rosbags'}
        if bad:
            offenders[str(f.relative_to(REPO))] = sorted(bad)
    assert not offenders, f'ROS imports where none may be: {offenders}'


def test_wire_imports_numpy_opencv_and_core_only():
    """The wire format (`pose4d_ros.wire`) is read and written by the nodes, the bag readers
    and the offline tools alike: besides the standard library it imports numpy, OpenCV and
    ours (`LAYERS`: core), nothing that needs a ROS install."""
    allowed = {'numpy', 'cv2', PACKAGE, '__future__'} | set(sys.stdlib_module_names)
    files = sorted((REPO / PACKAGE / 'wire').glob('*.py'))
    assert files
    offenders = {str(f.relative_to(REPO)): sorted(_imports(f) - allowed) for f in files}
    assert not {k: v for k, v in offenders.items() if v}


def test_boundary_check_catches_a_violation(tmp_path):
    bad = tmp_path / 'x.py'
    bad.write_text('import numpy\nfrom sensor_msgs.msg import Image\n'
                   'from rclpy.node import Node\n')
    assert {m for m in _imports(bad) if _is_ros(m)} == {'sensor_msgs', 'rclpy'}


# What each subpackage may import of ours (besides itself and the top package): core nothing
# above it; util (progress, log, machine facts) and wire (messages and their bytes <-> arrays)
# only core; the readers and the renderer no nodes or tools; training and evaluation the
# algorithms and the data, never a node or a verb; graph (the node graph in processes) the
# nodes too; the tools (cli) anything.
LAYERS = {'core': set(), 'util': {'core'}, 'wire': {'core'}, 'datasets': {'core', 'util', 'wire'},
          'synth': {'core', 'datasets', 'util'}, 'models': set(), 'peer': {'core'},
          'nodes': {'core', 'datasets', 'models', 'wire'},
          'training': {'core', 'datasets', 'models', 'util'},
          'evaluation': {'core', 'datasets', 'synth', 'peer', 'models', 'util', 'wire'},
          'graph': {'core', 'datasets', 'models', 'nodes', 'peer', 'util', 'wire'}}


def test_every_subpackage_has_its_layer():
    """A new subpackage says what it may import (`LAYERS`) before it imports anything."""
    found = {d.name for d in (REPO / PACKAGE).iterdir() if (d / '__init__.py').is_file()}
    assert found - {'cli'} == set(LAYERS)


def _our_imports(root: Path) -> dict[str, set[str]]:
    """{module: the modules of ours it imports, at the top or inside a function} under `root`
    (a directory holding the pose4d_ros package)."""
    files = {'.'.join(f.relative_to(root).with_suffix('').parts).removesuffix('.__init__'): f
             for f in (root / PACKAGE).rglob('*.py')}
    graph = {}
    for name, f in files.items():
        package = name if f.name == '__init__.py' else name.rpartition('.')[0]
        found = set()
        for node in ast.walk(ast.parse(f.read_text(), filename=str(f))):
            if isinstance(node, ast.Import):
                found.update(a.name for a in node.names)
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ''
                if node.level:
                    base = '.'.join([package.rsplit('.', node.level - 1)[0], base]).strip('.')
                found.update(f'{base}.{a.name}' if f'{base}.{a.name}' in files else base
                             for a in node.names)
        graph[name] = {m for m in found if m in files and m != name}
    return graph


def _layering_faults(graph: dict[str, set[str]]) -> list[str]:
    """Imports against `LAYERS`, and import cycles."""
    faults = []
    for name, deps in graph.items():
        layer = name.split('.')[1] if '.' in name else ''
        for dep in sorted(deps):
            other = dep.split('.')[1] if '.' in dep else ''
            if layer in LAYERS and other not in LAYERS[layer] | {layer, ''}:
                faults.append(f'{name} imports {dep}')
    try:
        graphlib.TopologicalSorter(graph).prepare()
    except graphlib.CycleError as exc:
        faults.append(f'import cycle: {" -> ".join(exc.args[1])}')
    return faults


def test_layering_no_wrong_way_imports_and_no_cycles():
    graph = _our_imports(REPO)
    assert len(graph) > 50 and graph[f'{PACKAGE}.cli.eval']  # the walk found the package
    assert not _layering_faults(graph)


def _verb_faults(graph: dict[str, set[str]]) -> list[str]:
    """A verb module (cli/<verb>.py; not main.py nor a shared _helper.py) importing another."""
    cli = f'{PACKAGE}.cli.'
    verbs = {n for n in graph if n.startswith(cli) and not n[len(cli):].startswith('_')
             and n != f'{cli}main'}
    return [f'{name} imports {dep}' for name in sorted(verbs)
            for dep in sorted(graph[name] & verbs)]


def test_verbs_share_code_through_packages_not_each_other():
    """`pose4d VERB` modules stay thin: what two verbs need lives in evaluation/, training/,
    datasets/, util/ or a shared cli/_helper.py, never in another verb."""
    graph = _our_imports(REPO)
    assert f'{PACKAGE}.cli.bench' in graph and f'{PACKAGE}.cli.eval' in graph
    assert not _verb_faults(graph)


def test_verb_check_catches_a_verb_importing_a_verb(tmp_path):
    cli = tmp_path / PACKAGE / 'cli'
    cli.mkdir(parents=True)
    for name, text in (('__init__', ''), ('_shared', ''), ('main', 'from . import a\n'),
                       ('a', 'from pose4d_ros.cli import _shared\n'),
                       ('b', 'def f():\n    from pose4d_ros.cli.a import x\n')):
        (cli / f'{name}.py').write_text(text)
    (tmp_path / PACKAGE / '__init__.py').write_text('')
    assert _verb_faults(_our_imports(tmp_path)) == [f'{PACKAGE}.cli.b imports {PACKAGE}.cli.a']


def test_test_modules_share_helpers_not_each_other():
    """What several tests use lives in helpers.py, harness.py or conftest.py."""
    offenders = {f.name: sorted(m for m in _imports(f) if m.startswith('test_'))
                 for f in sorted((REPO / 'test').glob('*.py'))}
    assert not {k: v for k, v in offenders.items() if v}


def test_layering_check_catches_a_violation(tmp_path):
    core = tmp_path / PACKAGE / 'core'
    core.mkdir(parents=True)
    for name, text in (('__init__', ''), ('a', 'from pose4d_ros.core import b\n'),
                       ('b', 'def f():\n    from . import a\n    from ..nodes import x\n')):
        (core / f'{name}.py').write_text(text)
    (tmp_path / PACKAGE / '__init__.py').write_text('')
    (tmp_path / PACKAGE / 'nodes').mkdir()
    (tmp_path / PACKAGE / 'nodes' / 'x.py').write_text('')
    faults = _layering_faults(_our_imports(tmp_path))
    assert f'{PACKAGE}.core.b imports {PACKAGE}.nodes.x' in faults
    assert any(f.startswith('import cycle') for f in faults), faults


# The team's sizes: no file of the package over MAX_FILE_LINES lines, no function over
# MAX_FUNCTION_LINES (from its `def` to its last line); a numba kernel may be longer when it
# says why (`KERNEL_REASON` in its docstring or in the comment right above it)
MAX_FILE_LINES = 700
MAX_FUNCTION_LINES = 100
KERNEL_REASON = 'more than 100 lines'


def _is_jit(expr: ast.expr) -> bool:
    """`njit`/`jit`, bare or called, plain or qualified (`nb.njit(cache=True)`)."""
    if isinstance(expr, ast.Call):
        expr = expr.func
    name = expr.attr if isinstance(expr, ast.Attribute) else getattr(expr, 'id', None)
    return name in ('njit', 'jit')


def _numba_kernels(tree: ast.Module) -> set[str]:
    """The names of the functions numba compiles: decorated (`@njit`, `@nb.njit(...)`) or
    passed to it (`f = nb.njit(cache=True)(g)`, `njit(g)`)."""
    kernels = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            if any(_is_jit(d) for d in node.decorator_list):
                kernels.add(node.name)
        elif isinstance(node, ast.Call) and (_is_jit(node.func) or (
                isinstance(node.func, ast.Call) and _is_jit(node.func.func))):
            kernels.update(a.id for a in node.args if isinstance(a, ast.Name))
    return kernels


def _says_why(node: ast.FunctionDef | ast.AsyncFunctionDef, lines: list[str]) -> bool:
    """Its docstring, or the comment lines right above its first decorator (or `def`), hold
    `KERNEL_REASON` (case, whitespace and line breaks aside)."""
    first = min([node.lineno, *(d.lineno for d in node.decorator_list)])
    above = []
    for line in reversed(lines[:first - 1]):
        if not line.strip().startswith('#'):
            break
        above.append(line.strip().lstrip('#'))
    text = ' '.join([ast.get_docstring(node) or '', *reversed(above)])
    return KERNEL_REASON in ' '.join(text.split()).lower()


def _size_faults(root: Path) -> list[str]:
    """Files over MAX_FILE_LINES and functions over MAX_FUNCTION_LINES under `root`'s
    package; a numba kernel over it only when it does not say why."""
    faults = []
    for f in sorted((root / PACKAGE).rglob('*.py')):
        name = f.relative_to(root).as_posix()
        text = f.read_text()
        lines = text.splitlines()
        if len(lines) > MAX_FILE_LINES:
            faults.append(f'{name}: {len(lines)} lines (at most {MAX_FILE_LINES})')
        tree = ast.parse(text, filename=str(f))
        kernels = _numba_kernels(tree)
        for node in ast.walk(tree):
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            length = node.end_lineno - node.lineno + 1
            if length <= MAX_FUNCTION_LINES:
                continue
            if node.name not in kernels:
                faults.append(f'{name}:{node.lineno} {node.name}: {length} lines (at most '
                              f'{MAX_FUNCTION_LINES})')
            elif not _says_why(node, lines):
                faults.append(f'{name}:{node.lineno} {node.name}: a numba kernel of {length} '
                              f'lines that does not say why ("{KERNEL_REASON}: ...")')
    return faults


def test_no_file_over_700_lines_no_function_over_100():
    """Numba kernels aside, each saying why it is one long function."""
    assert len(list((REPO / PACKAGE).rglob('*.py'))) > 50  # the walk found the package
    faults = _size_faults(REPO)
    assert not faults, '\n'.join(faults)


def test_size_check_catches_long_files_and_functions(tmp_path):
    (tmp_path / PACKAGE).mkdir()
    body = ''.join(f'    x{i} = {i}\n' for i in range(MAX_FUNCTION_LINES))
    kernels = {'plain': 'def f():\n', 'decorated': '@nb.njit(cache=True)\ndef f():\n',
               'assigned': 'def f():\n', 'why': '@njit\ndef f():\n    """More than\n'
               '    100 lines: one loop over pixels."""\n'}
    for name, head in kernels.items():
        tail = 'g = nb.njit(cache=True)(f)\n' if name == 'assigned' else ''
        (tmp_path / PACKAGE / f'{name}.py').write_text(head + body + tail)
    (tmp_path / PACKAGE / 'long.py').write_text('x = 1\n' * (MAX_FILE_LINES + 1))
    faults = _size_faults(tmp_path)
    assert faults == [
        f'{PACKAGE}/assigned.py:1 f: a numba kernel of {MAX_FUNCTION_LINES + 1} lines that does '
        f'not say why ("{KERNEL_REASON}: ...")',
        f'{PACKAGE}/decorated.py:2 f: a numba kernel of {MAX_FUNCTION_LINES + 1} lines that '
        f'does not say why ("{KERNEL_REASON}: ...")',
        f'{PACKAGE}/long.py: {MAX_FILE_LINES + 1} lines (at most {MAX_FILE_LINES})',
        f'{PACKAGE}/plain.py:1 f: {MAX_FUNCTION_LINES + 1} lines (at most '
        f'{MAX_FUNCTION_LINES})'], faults


@pytest.mark.parametrize('exe', sorted(NODE_MODULES))
def test_yaml_defaults_equal_code_defaults(exe):
    module = importlib.import_module(NODE_MODULES[exe])
    cfg = yaml.safe_load((REPO / 'config' / f'{exe}.yaml').read_text())
    assert list(cfg) == [exe], f'config/{exe}.yaml must have the node name {exe} at the top'
    flat: dict = {}

    def walk(prefix: str, d: dict) -> None:
        for k, v in d.items():
            if isinstance(v, dict):
                walk(f'{prefix}{k}.', v)
            else:
                flat[f'{prefix}{k}'] = v

    walk('', cfg[exe]['ros__parameters'])
    code = {p.name: p.default for p in module.PARAMS}
    assert flat == code
    for p in module.PARAMS:
        assert p.description, f'{exe}: parameter {p.name} has no description'
        assert p.validate(p.default) is None or p.name.endswith(('.bag', '.output')), \
            f'{exe}: default of {p.name} breaks its own rule'


def core_defaults() -> dict[str, object]:
    """{node parameter: its default as core holds it} (the stages' keywords, the configs'
    fields), for every node parameter that core has a default for."""
    from pose4d_ros.core.dpm.infer import SearchConfig
    from pose4d_ros.core.dpm.scale import ScaleConfig
    from pose4d_ros.core.foreground import ForegroundConfig
    from pose4d_ros.core.limb_lengths import DEFAULT_LIMB_LENGTHS_M
    from pose4d_ros.core.slqe import SlqeConfig
    from pose4d_ros.core.stages import DetectorStage, ForegroundStage, IkStage, TrackerStage

    def keyword(stage: type, name: str) -> object:
        return inspect.signature(stage).parameters[name].default

    def fields(group: str, config: object, names: str) -> dict[str, object]:
        return {f'{group}.{n}': getattr(config, n) for n in names.split()}

    scale = ScaleConfig()
    (arm, forearm), (thigh, shin) = (DEFAULT_LIMB_LENGTHS_M[limb] for limb in ('left_arm',
                                                                               'left_leg'))
    return {
        **fields('foreground', ForegroundConfig(), 'max_region_area_px mser_delta '
                 'mser_max_variation depth_near_m depth_far_m floor_remove'),
        'foreground.temporal': keyword(ForegroundStage, 'temporal'),
        **fields('detector', SearchConfig(), 'n_levels margin arm_prior'),
        'detector.person_scales': list(scale.factors),
        'detector.scale_warm_up_frames': scale.warm_up_frames,
        'detector.scale_probe_every': scale.probe_every,
        'detector.min_confidence': keyword(DetectorStage, 'min_confidence'),
        **fields('tracker', SlqeConfig(), 'coupling process_noise measurement_noise_px '
                 'gate_chi2 max_missed_frames max_dt_s'),
        'tracker.depth_std_m': keyword(TrackerStage, 'depth_std_m'),
        'ik.use_depth': keyword(IkStage, 'use_depth'),
        'ik.learn_lengths': keyword(IkStage, 'learn'),
        'ik.upper_arm_length_m': arm, 'ik.forearm_length_m': forearm,
        'ik.thigh_length_m': thigh, 'ik.shin_length_m': shin,
    }


@pytest.mark.parametrize('exe', sorted(NODE_MODULES))
def test_node_defaults_equal_core_defaults(exe):
    """A node parameter with a default in core takes it from there (every default in one
    place): the `Param` tables and core agree, in value and type."""
    core = core_defaults()
    params = {p.name: p.default for p in importlib.import_module(NODE_MODULES[exe]).PARAMS}
    shared = {name: (params[name], core[name]) for name in params.keys() & core.keys()}
    assert all(a == b and type(a) is type(b) for a, b in shared.values()), shared
    if exe in ('foreground', 'detector', 'tracker', 'ik', 'pipeline'):
        assert shared, f'{exe}: no parameter checked against core'


def published_topics() -> set[str]:
    """Every topic a node of ours publishes (the topic strings of `create_publisher` calls in
    pose4d_ros/nodes), and the camera topics the replay plays into the foreground node."""
    from pose4d_ros.nodes.foreground import CAMERA_TOPICS

    topics = {'/' + topic.lstrip('/') for _, topic, _ in CAMERA_TOPICS}
    for path in (REPO / 'pose4d_ros' / 'nodes').glob('*.py'):
        for node in ast.walk(ast.parse(path.read_text())):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                    and node.func.attr == 'create_publisher' and len(node.args) >= 2
                    and isinstance(node.args[1], ast.Constant)):
                topics.add('/' + node.args[1].value.lstrip('/'))
    return topics


def test_rviz_config_shows_what_the_graph_publishes():
    from pose4d_ros.datasets.cad60_bag import FRAME_ID

    rviz = yaml.safe_load((REPO / 'config' / 'pose4d.rviz').read_text())
    manager = rviz['Visualization Manager']
    assert manager['Global Options']['Fixed Frame'] == FRAME_ID  # the camera's, as in the bags
    displays = {d['Class'].split('/')[-1]: d for d in manager['Displays']}
    assert {'Image', 'PointCloud2', 'MarkerArray', 'TF'} <= set(displays)
    published = published_topics()
    assert {'/pose4d/skeleton/markers', '/tf', '/camera/color/image_raw'} <= published
    for display in manager['Displays']:
        if 'Topic' in display:
            assert display['Topic']['Value'] in published, display['Name']
    # a sensor stream is best effort; a reliable subscription would not match the driver's
    assert displays['Image']['Topic']['Reliability Policy'] == 'Best Effort'


def test_written_files_get_the_usual_permissions(tmp_path):
    from pose4d_ros.core.files import write_atomic

    mask = os.umask(0o022)
    os.umask(mask)
    write_atomic(tmp_path / 'out' / 'a.json', b'{}')
    assert (tmp_path / 'out' / 'a.json').stat().st_mode & 0o777 == 0o666 & ~mask
    assert [p.name for p in (tmp_path / 'out').iterdir()] == ['a.json']
