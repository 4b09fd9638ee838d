"""ament_python package pose4d_ros.

colcon builds it through this file (executables go to lib/pose4d_ros, see setup.cfg); the
Makefile installs it into the project's virtual environment with pip.
"""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'pose4d_ros'

# One executable per node, plus the offline `pose4d` command. `ros2 run pose4d_ros <name>`.
EXECUTABLES = {
    'pose4d': 'pose4d_ros.cli.main:main',
    'replay': 'pose4d_ros.nodes.replay:main',
    'recorder': 'pose4d_ros.nodes.recorder:main',
    'foreground': 'pose4d_ros.nodes.foreground:main',
    'detector': 'pose4d_ros.nodes.detector:main',
    'tracker': 'pose4d_ros.nodes.tracker:main',
    'ik': 'pose4d_ros.nodes.ik:main',
    'pipeline': 'pose4d_ros.nodes.pipeline:main',
    'composed': 'pose4d_ros.nodes.composed:main',
}

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(include=[PACKAGE, f'{PACKAGE}.*']),
    package_data={f'{PACKAGE}.models': ['*.npz', '*.json', '*.md']},
    data_files=[
        ('share/ament_index/resource_index/packages', [f'resource/{PACKAGE}']),
        (f'share/{PACKAGE}', ['package.xml']),
        (f'share/{PACKAGE}/config',
         sorted(glob('config/*.yaml') + glob('config/*.xml') + glob('config/*.rviz'))),
        *[
            (f'share/{PACKAGE}/{d}', sorted(f for f in glob(f'{d}/*')))
            for d in sorted(glob('bags/*'))
        ],
    ],
    python_requires='>=3.10',
    install_requires=['setuptools'],
    zip_safe=False,
    maintainer='pose4d_ros maintainers',
    maintainer_email='maintainers@pose4d-ros.org',
    description='Live RGB-D human pose tracking (4D deformable part model + Kalman filter + IK).',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [f'{name} = {target}' for name, target in EXECUTABLES.items()],
    },
)
