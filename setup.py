from glob import glob

from setuptools import find_packages, setup

package_name = 'motor_id'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
        ('share/' + package_name + '/bags', glob('bags/*.mcap') + glob('bags/*.md')),
    ],
    install_requires=['setuptools', 'numpy', 'scipy', 'numba', 'matplotlib', 'pyserial',
                      'mcap', 'PyYAML', 'rosbags', 'robotpy-wpiutil'],
    extras_require={
        # pytest 9.2 ignores pytest-xdist 3.8's group suffix on node ids, so --dist
        # loadgroup no longer keeps the ROS node tests on one worker (test/conftest.py checks)
        'test': ['pytest<9.2', 'pytest-xdist', 'hypothesis', 'mcap-ros2-support',
                 'colcon-common-extensions', 'import-linter', 'pygad', 'cma', 'psutil',
                 'control', 'ruff', 'mypy', 'dask[distributed]', 'pyarrow'],
        'fleet': ['dask[distributed]', 'pyarrow'],
        'bench': ['pygad', 'cma', 'psutil'],
    },
    zip_safe=True,
    maintainer='motor_id developers',
    maintainer_email='dev@motor-id.invalid',
    description='DC motor parameter identification: constrained Elman net + GA, in ROS 2',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'motor-id = motor_id.cli:main',
            'driver = motor_id.nodes.driver:main',
            'identifier = motor_id.nodes.identifier:main',
            'sim-robot = motor_id.testing.sim_robot:main',
            'experiment = motor_id.nodes.experiment:main',
        ],
    },
)
