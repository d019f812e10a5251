"""ament_python build of herd_ros: `colcon build` on a ROS 2 Jazzy install, `pip install .`
on the pip path."""
import os
import sys
from glob import glob

from setuptools import find_packages, setup

package_name = 'herd_ros'
HERE = os.path.dirname(os.path.abspath(__file__))


def compiled_kernels():
    """The collar kernels compiled ahead of time (herd_ros/ingest/aot.py), an optional
    extension: where numba cannot be imported here, or (setuptools' ``optional``) where no C
    compiler builds it, herd_ros runs the same kernels through numba's JIT instead.

    Returns (ext_modules, cmdclass). The build command compiles the kernels only when the
    extension in the build directory is older than their sources (``make`` reinstalls the
    package on every run; the compilation takes ~10 s)."""
    sys.path.insert(0, HERE)
    try:
        from herd_ros.ingest.aot import SOURCES, compiler
        sources = [os.path.join('herd_ros', 'ingest', name) for name in SOURCES]
        ext = compiler().distutils_extension(optional=True, depends=sources)
    except Exception as exc:  # noqa: BLE001 - any failure here only costs speed
        print(f'herd_ros: the collar kernels are not compiled ahead of time ({exc}); numba '
              f'compiles them at first use', file=sys.stderr)
        return [], {}
    finally:
        sys.path.remove(HERE)
    from setuptools.command import build_ext  # numba's, once distutils_extension ran

    class BuildExt(build_ext.build_ext):
        def build_extension(self, extension):
            target = self.get_ext_fullpath(extension.name)
            inputs = list(extension.sources) + list(extension.depends)
            if (not self.force and os.path.exists(target)
                    and all(os.path.getmtime(f) <= os.path.getmtime(target) for f in inputs)):
                print(f'herd_ros: {target} is up to date', file=sys.stderr)
                return
            super().build_extension(extension)

    return [ext], {'build_ext': BuildExt}


EXT_MODULES, CMDCLASS = compiled_kernels()

NODES = ['gps_ingest', 'estimator', 'controller', 'fleet_sim', 'herd_sim', 'replay', 'record']

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', sorted(glob('config/*.yaml'))),
        ('share/' + package_name + '/launch', sorted(glob('launch/*.launch.py'))),
        ('share/' + package_name + '/bags', sorted(glob('bags/*.md') + glob('bags/*.csv'))),
        ('share/' + package_name + '/bags/cows_3x1h', sorted(glob('bags/cows_3x1h/*'))),
        ('share/' + package_name + '/bags/baboons_1h', sorted(glob('bags/baboons_1h/*'))),
    ],
    install_requires=['setuptools', 'numpy', 'scipy', 'pandas', 'numba', 'filterpy', 'rosbags',
                      'PyYAML', 'matplotlib', 'tqdm'],
    ext_modules=EXT_MODULES,
    cmdclass=CMDCLASS,
    zip_safe=False,
    maintainer='herd_ros maintainers',
    maintainer_email='maintainers@herd-ros.invalid',
    description='Learn herd dynamics from GPS collars and drive robot fleets with them.',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [f'{n} = herd_ros.nodes.{n}:main' for n in NODES]
        + ['herd-ros = herd_ros.cli.main:main'],
    },
)
