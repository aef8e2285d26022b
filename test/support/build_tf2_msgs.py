"""Build the ``tf2_msgs`` Python package (TFMessage) from its ``.msg`` text with the rosidl
generators that PyPI's ROS 2 Jazzy wheels install (tf2_msgs itself is not on PyPI).

The same steps as ``rosidl_generate_interfaces`` in a colcon build: ``.msg`` -> ``.idl`` ->
type hash, C structs (rosidl_generator_c), the C type supports (introspection, Fast DDS,
dispatch), the Python module (rosidl_generator_py); then gcc/g++ compile them against the
headers and libraries of the installed message packages. Nothing is stubbed: the result is
what ``ros-jazzy-tf2-msgs`` contains for this message.

``python build_tf2_msgs.py OUT`` -> ``OUT/python`` (put on PYTHONPATH) and ``OUT/lib``
(put on LD_LIBRARY_PATH). Needs gcc, g++ and catkin_pkg (for rosidl_adapter).
"""
from __future__ import annotations

import importlib
import inspect
import os
import pathlib
import shutil
import subprocess
import sys
import sysconfig

TF_MESSAGE_MSG = "geometry_msgs/TransformStamped[] transforms\n"
PACKAGE = "tf2_msgs"
DEPENDENCIES = ("geometry_msgs", "std_msgs", "builtin_interfaces")
GENERATORS = {
    "c": "rosidl_generator_c.cli:GenerateC",
    "introspection_c": "rosidl_typesupport_introspection_c.cli:GenerateIntrospectionCTypesupport",
    "fastrtps_c": "rosidl_typesupport_fastrtps_c.cli:GenerateFastRTPSCTypesupport",
    "typesupport_c": "rosidl_typesupport_c.cli:GenerateCTypesupport",
    "py": "rosidl_generator_py.cli:GeneratePython",
}


def _run(cmd):
    subprocess.run(cmd, check=True)


def build(out: pathlib.Path, prefix: pathlib.Path = pathlib.Path(sys.prefix)) -> pathlib.Path:
    out = pathlib.Path(out).resolve()
    src = out / "src"
    gen = out / "gen"
    lib = out / "lib"
    py = out / "python" / PACKAGE
    for d in (src / PACKAGE / "msg", lib, py):
        d.mkdir(parents=True, exist_ok=True)
    (src / PACKAGE / "msg" / "TFMessage.msg").write_text(TF_MESSAGE_MSG)
    os.environ.setdefault("AMENT_PREFIX_PATH", str(prefix))
    iface = [f"{src / PACKAGE}:msg/TFMessage.msg"]
    for name, spec in GENERATORS.items():
        module, cls = spec.split(":")
        ext = getattr(importlib.import_module(module), cls)(name)
        kwargs = {}
        if "type_description_files" in inspect.signature(ext.generate).parameters:
            kwargs["type_description_files"] = None
        ext.generate(PACKAGE, iface, [prefix / "share"], output_path=gen / name / PACKAGE, **kwargs)

    inc = prefix / "include"
    includes = [f"-I{gen / n}" for n in ("c", "introspection_c", "fastrtps_c")]
    includes += [f"-I{d}" for d in sorted(inc.iterdir()) if d.is_dir()] + [f"-I{inc}"]
    includes += [f"-I{sysconfig.get_paths()['include']}"]
    numpy_inc = None
    try:
        import numpy

        numpy_inc = numpy.get_include()
    except ImportError:
        pass
    if numpy_inc:
        includes.append(f"-I{numpy_inc}")
    libdir = prefix / "lib"
    link = [f"-L{lib}", f"-L{libdir}", f"-Wl,-rpath,{lib}", f"-Wl,-rpath,{libdir}"]

    def deps(kind):
        return [f"-l{d}__{kind}" for d in DEPENDENCIES]

    def shared(name, sources, libs, cxx=False):
        compiler = "g++" if cxx else "gcc"
        std = ["-std=c++17"] if cxx else ["-std=c11"]
        _run([compiler, "-shared", "-fPIC", "-O1", *std, *includes, *map(str, sources), "-o", str(name),
              *link, *libs])

    g = gen
    c_lib = lib / f"lib{PACKAGE}__rosidl_generator_c.so"
    shared(c_lib, sorted((g / "c" / PACKAGE / "msg" / "detail").glob("*.c")),
           deps("rosidl_generator_c") + ["-lrosidl_runtime_c", "-lrcutils"])
    intro = lib / f"lib{PACKAGE}__rosidl_typesupport_introspection_c.so"
    shared(intro, sorted((g / "introspection_c" / PACKAGE / "msg" / "detail").glob("*.c")),
           [f"-l{PACKAGE}__rosidl_generator_c"] + deps("rosidl_typesupport_introspection_c")
           + deps("rosidl_generator_c") + ["-lrosidl_runtime_c", "-lrcutils"])
    fast = lib / f"lib{PACKAGE}__rosidl_typesupport_fastrtps_c.so"
    shared(fast, sorted((g / "fastrtps_c" / PACKAGE / "msg" / "detail").glob("*.cpp")),
           [f"-l{PACKAGE}__rosidl_generator_c"] + deps("rosidl_typesupport_fastrtps_c")
           + deps("rosidl_generator_c") + ["-lrosidl_typesupport_fastrtps_c", "-lrosidl_typesupport_fastrtps_cpp",
                                           "-lfastcdr", "-lrmw", "-lrosidl_runtime_c", "-lrcutils"], cxx=True)
    ts = lib / f"lib{PACKAGE}__rosidl_typesupport_c.so"
    shared(ts, sorted((g / "typesupport_c" / PACKAGE / "msg").glob("*.cpp")),
           [f"-l{PACKAGE}__rosidl_generator_c", "-lrosidl_typesupport_c", "-lrcpputils", "-lrcutils",
            "-lrosidl_runtime_c"], cxx=True)
    pygen = g / "py" / PACKAGE
    pylib = lib / f"lib{PACKAGE}__rosidl_generator_py.so"
    shared(pylib, sorted((pygen / "msg").glob("*_s.c")),
           [f"-l{PACKAGE}__rosidl_generator_c", f"-l{PACKAGE}__rosidl_typesupport_c"]
           + deps("rosidl_generator_py") + deps("rosidl_generator_c") + ["-lrosidl_runtime_c", "-lrcutils"])
    for tsname in ("rosidl_typesupport_c", "rosidl_typesupport_introspection_c", "rosidl_typesupport_fastrtps_c"):
        shared(py / f"{PACKAGE}_s__{tsname}.so", [pygen / f"_{PACKAGE}_s.ep.{tsname}.c"],
               [f"-l{PACKAGE}__rosidl_generator_py", f"-l{PACKAGE}__{tsname}", f"-l{PACKAGE}__rosidl_generator_c",
                "-lrosidl_runtime_c", "-lrcutils"])
    shutil.copytree(pygen / "msg", py / "msg", dirs_exist_ok=True,
                    ignore=shutil.ignore_patterns("*.c", "*.h", "tmp"))
    (py / "__init__.py").write_text("")
    share = out / "share" / PACKAGE / "msg"
    share.mkdir(parents=True, exist_ok=True)
    (share / "TFMessage.msg").write_text(TF_MESSAGE_MSG)
    return out


def environment(out, base: dict | None = None) -> dict:
    """``base`` (default: this process's environment) with the build at ``out`` importable:
    ``OUT/python`` and the checkout on PYTHONPATH, ``OUT/lib`` on LD_LIBRARY_PATH."""
    env = dict(os.environ if base is None else base)
    repo = pathlib.Path(__file__).resolve().parents[2]
    out = pathlib.Path(out)
    env["PYTHONPATH"] = os.pathsep.join([str(out / "python"), str(repo), env.get("PYTHONPATH", "")])
    env["LD_LIBRARY_PATH"] = os.pathsep.join([str(out / "lib"), env.get("LD_LIBRARY_PATH", "")])
    return env


if __name__ == "__main__":
    print(build(pathlib.Path(sys.argv[1])))
