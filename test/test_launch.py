"""The launch file, read as source (the `launch` package is not installable here)."""

import ast
import os
import re

import yaml

from motor_id.testing.ros import REPO

LAUNCH = os.path.join(REPO, 'launch', 'motor_id.launch.py')


def _tree():
    with open(LAUNCH) as fh:
        source = fh.read()
    return compile(source, LAUNCH, 'exec', ast.PyCF_ONLY_AST)


def _calls(tree, name):
    return [n for n in ast.walk(tree) if isinstance(n, ast.Call)
            and getattr(n.func, 'id', getattr(n.func, 'attr', None)) == name]


def _kw(call, name):
    return next((k.value for k in call.keywords if k.arg == name), None)


def test_launch_file_declares_every_argument_it_uses():
    tree = _tree()
    declared = {c.args[0].value for c in _calls(tree, 'DeclareLaunchArgument')}
    used = {c.args[0].value for c in _calls(tree, 'LaunchConfiguration')}
    assert {'namespace', 'device', 'joint', 'driver_params', 'identifier_params'} <= declared
    assert used == declared
    for call in _calls(tree, 'DeclareLaunchArgument'):
        assert _kw(call, 'description') is not None, call.args[0].value
    assert any(isinstance(n, ast.FunctionDef) and n.name == 'generate_launch_description'
               for n in tree.body)


def test_launch_file_starts_installed_executables_in_the_namespace():
    from motor_id.nodes import driver, identifier
    with open(os.path.join(REPO, 'setup.py')) as fh:
        setup_py = fh.read()
    scripts = dict(re.findall(r"'(\w+) = (motor_id\.nodes\.\w+):main'", setup_py))
    nodes = _calls(_tree(), 'Node')
    specs = {'driver': driver.PARAMETERS, 'identifier': identifier.PARAMETERS}
    assert sorted(_kw(n, 'executable').value for n in nodes) == ['driver', 'identifier']
    for node in nodes:
        exe = _kw(node, 'executable').value
        assert scripts[exe] == f'motor_id.nodes.{exe}'
        assert _kw(node, 'package').value == 'motor_id'
        assert _kw(node, 'namespace').id == 'namespace'
        overrides = [d for d in _kw(node, 'parameters').elts if isinstance(d, ast.Dict)]
        names = {k.value for d in overrides for k in d.keys}
        assert names and names <= {s.name for s in specs[exe]}, names
    # tied to the launch process: the nodes stop when it ends, however it ends
    assert all(_kw(n, 'prefix').id == 'tied' for n in nodes)
    # installed where FindPackageShare looks: share/motor_id/{launch,config}
    assert "'/launch', glob('launch/*.launch.py')" in setup_py
    assert "'/config', glob('config/*.yaml')" in setup_py


def test_parameter_files_the_launch_file_names_exist_and_fit_any_namespace():
    tree = _tree()
    files = {c.elts[1].value for c in
             (n.args[0] for n in _calls(tree, 'PathJoinSubstitution'))
             if isinstance(c, ast.List) and getattr(c.elts[0], 'id', None) == 'CONFIG'}
    assert files == {'driver.yaml', 'identifier.yaml'}
    with open(os.path.join(REPO, 'config', 'identifier.yaml')) as fh:
        params = yaml.safe_load(fh)
    assert list(params) == ['/**']
    from motor_id.nodes.identifier import PARAMETERS
    assert set(params['/**']['ros__parameters']) == {s.name for s in PARAMETERS}
    for name in files:
        assert os.path.isfile(os.path.join(REPO, 'config', name))


def test_launch_prefix_ties_a_node_to_the_launch_process():
    """The prefix the launch file gives its nodes, run as launch runs it (its words, then
    the node's command): the node runs, and its parent must be the launch process."""
    import shlex
    import subprocess
    import sys

    from motor_id.lifeline import launcher_prefix
    prefix = shlex.split(shlex.join(launcher_prefix(os.getpid())))
    ok = subprocess.run(prefix + [sys.executable, '-c', 'print("node")'], capture_output=True,
                        text=True, timeout=60)
    assert ok.returncode == 0 and ok.stdout == 'node\n', ok.stderr
    other = launcher_prefix(os.getppid())     # a prefix made by another process
    assert subprocess.run(other + ['true'], timeout=60).returncode == 128 + 15
