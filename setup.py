"""ament_python package cr_control: holds the Python packages cr_control and cr_sim."""

import shutil
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup
from setuptools.command.build_py import build_py

PACKAGE = "cr_control"

# Per-scheme executables only choose the scheme of the one generic controller node.
SCHEMES = [
    "adaptive_impedance",
    "robust_adaptive_impedance",
    "nn_adaptive_impedance",
    "impedance",
    "fuzzy_unidirectional",
    "moving_object_adaptive",
    "moving_object_nn",
    "backstepping_force",
    "mrac_force",
    "cmmsd_backstepping",
    "fjr_robust_adaptive",
    "fjr_singular_perturbation",
]


class BuildPyWithKernels(build_py):
    """Also carries the numba kernels already compiled in the source tree (``__pycache__``'s
    ``*.nbi`` index and ``*.nbc`` data files, which numba keys by the source's content, not
    its path): a tree warmed up with ``python -m cr_control.tools.warm_up`` installs nodes
    that start without compiling them again."""

    def run(self) -> None:
        super().run()
        for package in self.packages:
            cache = Path(self.get_package_dir(package)) / "__pycache__"
            kernels = sorted(cache.glob("*.nbi")) + sorted(cache.glob("*.nbc"))
            if not kernels:
                continue
            target = Path(self.build_lib, *package.split("."), "__pycache__")
            target.mkdir(parents=True, exist_ok=True)
            for kernel in kernels:
                shutil.copy2(kernel, target / kernel.name)


setup(
    name=PACKAGE,
    cmdclass={"build_py": BuildPyWithKernels},
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={"cr_control.core": ["fastdds_profile.xml", "fastdds_profile_lockstep.xml",
                                     "fastdds_profile_visitor.xml"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml") + glob("config/*.urdf")
         + glob("config/*.json")),
    ]
    # the robots' wiping tasks (cr_session --robot): config/robots/<robot>/*.yaml
    + [(f"share/{PACKAGE}/config/robots/{robot}", glob(f"config/robots/{robot}/*.yaml"))
       for robot in sorted(p.rsplit("/", 1)[-1] for p in glob("config/robots/*"))]
    # Launch files, if any, where `ros2 launch cr_control ...` looks for them.
    + ([(f"share/{PACKAGE}/launch", glob("launch/*"))] if glob("launch/*") else []),
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="cr_control maintainers",
    maintainer_email="maintainers@cr-control.invalid",
    description="Force/position control of constrained robots (thesis controllers as ROS 2 nodes).",
    license="Apache-2.0",
    tests_require=["pytest"],
    entry_points={
        # Each through cr_control.tools.entry: Ctrl-C while a tool starts is one line, exit 130.
        "console_scripts": [
            f"{tool} = cr_control.tools.entry:{tool}" for tool in (
                "plant", "recorder", "cr_session", "cr_analyze", "cr_benchmark", "cr_param",
                "cr_lifecycle", "cr_fuzz", "cr_identify_tool", "cr_sweep", "cr_tune",
                "cr_reproduce")
        ]
        + [f"{name} = cr_control.tools.entry:controller_{name}" for name in SCHEMES],
    },
)
