"""package.xml is well formed and declares every third-party module the package imports.

Both routes must know every dependency: rosdep reads package.xml (colcon route), pip
reads setup.py's install_requires (pip route). A new import of a module not in
MODULE_DEPENDENCIES fails here until someone adds it to the table and to both files.
"""

import ast
import sys
import xml.etree.ElementTree as ET

import pytest

import tocontrol_ros

PACKAGE = "tocontrol_ros"

# Top-level module -> (rosdep key in package.xml, pip distribution in install_requires).
# The pip side names what brings the module in the pip route: message packages and
# ament_index_python come inside the ROS wheels.
MODULE_DEPENDENCIES = {
    "rclpy": ("rclpy", "ros-jazzy-rclpy"),
    "ament_index_python": ("ament_index_python", "ros-jazzy-rclpy"),
    "rcl_interfaces": ("rcl_interfaces", "ros-jazzy-rclpy"),
    "rosgraph_msgs": ("rosgraph_msgs", "ros-jazzy-rclpy"),
    "builtin_interfaces": ("builtin_interfaces", "ros-jazzy-common-interfaces"),
    "std_msgs": ("std_msgs", "ros-jazzy-common-interfaces"),
    "std_srvs": ("std_srvs", "ros-jazzy-common-interfaces"),
    "geometry_msgs": ("geometry_msgs", "ros-jazzy-common-interfaces"),
    "nav_msgs": ("nav_msgs", "ros-jazzy-common-interfaces"),
    "sensor_msgs": ("sensor_msgs", "ros-jazzy-common-interfaces"),
    "trajectory_msgs": ("trajectory_msgs", "ros-jazzy-common-interfaces"),
    "diagnostic_msgs": ("diagnostic_msgs", "ros-jazzy-common-interfaces"),
    "visualization_msgs": ("visualization_msgs", "ros-jazzy-common-interfaces"),
    "numpy": ("python3-numpy", "numpy"),
    "scipy": ("python3-scipy", "scipy"),
    "yaml": ("python3-yaml", "PyYAML"),
    "matplotlib": ("python3-matplotlib", "matplotlib"),
    "urdf_parser_py": ("urdfdom_py", "urdfdom-py"),
    "casadi": ("casadi-pip", "casadi"),
    # rosdistro has no key for `mcap` alone; the mcap-ros2-support key brings it in.
    "mcap": ("mcap-ros2-support", "mcap"),
    "mcap_ros2": ("mcap-ros2-support", "mcap-ros2-support"),
    "toppra": ("python3-toppra-pip", "toppra"),
    # Jazzy's coal package (formerly hpp-fcl) carries its Python bindings.
    "coal": ("coal", "coal"),
}

# Interface packages with no wheel: top-level module -> rosdep key. The pip route builds them
# from interfaces/<module>/ (scripts/dev); colcon must skip that folder (COLCON_IGNORE) and
# take the distribution's package.
BUILT_INTERFACES = {
    "control_msgs": "control_msgs",
    "tf2_msgs": "tf2_msgs",
}

# The project's own interface packages (interfaces/<module>/): top-level module -> rosdep key.
# Built on both routes: scripts/dev builds them into the venv (pip route); colcon builds them
# in a workspace (no COLCON_IGNORE); package.xml depends on them.
OWN_INTERFACES = {
    "tocontrol_msgs": "tocontrol_msgs",
}

# Optional modules: top-level module -> (extra, pip distribution). Declared in that extra of
# setup.py's extras_require, not in install_requires nor package.xml (rosdistro has no key),
# and imported only inside functions, so that the package works without them.
OPTIONAL_DEPENDENCIES = {  # top-level module -> (setup.py extra, pip distribution)
    "ray": ("ray", "ray"),  # `batch --ray`
    # The bounded solve's detour seed with a scene (core/direct/detour.py; the `collision`
    # extra): without it a plan with a scene says it has no detour seed.
    "ompl": ("collision", "ompl"),
}


@pytest.fixture(scope="module")
def package_xml(repo):
    return ET.parse(repo / "package.xml").getroot()


def _texts(root, tag):
    return [element.text.strip() for element in root.findall(tag)]


def _third_party_imports(repo):
    """Map top-level module -> ["file:line", ...] for non-stdlib, non-project imports."""
    found = {}
    for path in sorted((repo / PACKAGE).rglob("*.py")):
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                modules = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                modules = [node.module]
            else:
                continue
            for module in modules:
                top = module.split(".")[0]
                if top == PACKAGE or top in sys.stdlib_module_names:
                    continue
                where = f"{path.relative_to(repo)}:{node.lineno}"
                found.setdefault(top, []).append(where)
    return found


def _requirement_name(spec):
    for sep in "<>=!~;[ ":
        spec = spec.split(sep)[0]
    return spec.strip().lower().replace("_", "-")


def test_format_3_ament_python(package_xml):
    assert package_xml.tag == "package"
    assert package_xml.get("format") == "3"
    assert package_xml.findtext("name") == PACKAGE
    assert package_xml.findtext("export/build_type") == "ament_python"
    assert _texts(package_xml, "maintainer") and _texts(package_xml, "license")


def test_versions_agree(package_xml, setup_keywords):
    assert package_xml.findtext("version") == setup_keywords["version"]
    assert tocontrol_ros.__version__ == setup_keywords["version"]


def test_no_duplicate_dependencies(package_xml):
    keys = _texts(package_xml, "exec_depend") + _texts(package_xml, "depend")
    assert len(keys) == len(set(keys))


def test_every_import_is_declared(repo, package_xml, setup_keywords):
    rosdep_keys = set(_texts(package_xml, "exec_depend") + _texts(package_xml, "depend"))
    pip_names = {_requirement_name(r) for r in setup_keywords["install_requires"]}
    unknown, undeclared = [], []
    for module, places in sorted(_third_party_imports(repo).items()):
        if module in OPTIONAL_DEPENDENCIES:
            continue
        interfaces = {**BUILT_INTERFACES, **OWN_INTERFACES}
        if module in interfaces:
            if interfaces[module] not in rosdep_keys:
                undeclared.append(f"package.xml lacks <exec_depend>{interfaces[module]}"
                                  f"</exec_depend> for {module}")
            continue
        if module not in MODULE_DEPENDENCIES:
            unknown.append(f"{module} ({', '.join(places)})")
            continue
        key, pip_name = MODULE_DEPENDENCIES[module]
        if key not in rosdep_keys:
            undeclared.append(f"package.xml lacks <exec_depend>{key}</exec_depend> for {module}")
        if _requirement_name(pip_name) not in pip_names:
            undeclared.append(f"setup.py install_requires lacks {pip_name} for {module}")
    assert not unknown, (
        "imports with no entry in MODULE_DEPENDENCIES (add the rosdep key and pip "
        f"distribution there, and declare both): {unknown}"
    )
    assert not undeclared, undeclared


def test_scanner_sees_the_demo_imports(repo):
    # Guards the scan itself: the demo imports ament_index_python inside a function.
    assert "ament_index_python" in _third_party_imports(repo)


def _top_level_imports(repo):
    """Top-level modules imported at module level (not inside a function) -> files."""
    found = {}
    for path in sorted((repo / PACKAGE).rglob("*.py")):
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in tree.body:
            if isinstance(node, ast.Import):
                modules = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                modules = [node.module]
            else:
                continue
            for module in modules:
                found.setdefault(module.split(".")[0], []).append(str(path.relative_to(repo)))
    return found


def test_optional_imports_are_extras_imported_lazily(repo, setup_keywords):
    extras = setup_keywords["extras_require"]
    required = {_requirement_name(r) for r in setup_keywords["install_requires"]}
    eager = _top_level_imports(repo)
    for module, (extra, pip_name) in OPTIONAL_DEPENDENCIES.items():
        assert _requirement_name(pip_name) in {_requirement_name(r)
                                               for r in extras.get(extra, [])}, \
            f"setup.py extras_require[{extra!r}] lacks {pip_name}"
        assert _requirement_name(pip_name) not in required, \
            f"{pip_name} is optional: keep it out of install_requires"
        assert module not in eager, \
            f"{module} is optional: import it inside functions, not at the top of {eager[module]}"
    assert "ray" in _third_party_imports(repo), "the scan no longer sees ray_backend's import"


def test_built_interfaces_are_in_the_tree_and_skipped_by_colcon(repo):
    for module in BUILT_INTERFACES:
        folder = repo / "interfaces" / module
        assert (folder / "package.xml").is_file() and (folder / "CMakeLists.txt").is_file()
        assert (folder / "COLCON_IGNORE").is_file(), f"colcon would build {folder}"
    assert "interfaces" in (repo / "scripts" / "dev").read_text()


def test_own_interfaces_are_built_on_both_routes(repo):
    for module in OWN_INTERFACES:
        folder = repo / "interfaces" / module
        assert (folder / "package.xml").is_file() and (folder / "CMakeLists.txt").is_file()
        assert not (folder / "COLCON_IGNORE").exists(), f"colcon must build {folder}"
