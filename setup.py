"""ament_python build of softseq_ros (also installable with pip on machines without ROS)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'softseq_ros'

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*', 'bench', 'bench.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/launch', glob('launch/*.launch.py')),
        ('share/' + PACKAGE + '/config', glob('config/*.yaml')),
        ('share/' + PACKAGE + '/config/params', glob('config/params/*.yaml')),
        ('share/' + PACKAGE + '/config/segments', glob('config/segments/*.csv')),
        ('share/' + PACKAGE + '/config/library', glob('config/library/*.csv')),
        ('share/' + PACKAGE + '/config/reference', glob('config/reference/*.yaml')),
        ('share/' + PACKAGE + '/config/experiments', glob('config/experiments/*.csv')),
        ('share/' + PACKAGE + '/config/foxglove', glob('config/foxglove/*.json')),
        ('share/' + PACKAGE + '/config/designs', glob('config/designs/*.yaml')),
    ],
    install_requires=['setuptools'],
    extras_require={'fem': ['felupe', 'tensortrax', 'pymetis', 'dask', 'distributed'],
                    'scatter': ['SALib']},
    zip_safe=True,
    maintainer='softseq_ros maintainers',
    maintainer_email='maintainers@softseq.dev',
    description='Emulated rig of a soft actuator with a hardware-encoded inflation sequence.',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'softseq = softseq_ros.cli:main',
            'syringe_pump = softseq_ros.nodes.entry:syringe_pump',
            'managed_syringe_pump = softseq_ros.nodes.entry:managed_syringe_pump',
            'actuator = softseq_ros.nodes.entry:actuator',
            'camera = softseq_ros.nodes.entry:camera',
            'pressure_hold = softseq_ros.nodes.entry:pressure_hold',
            'recorder = softseq_ros.nodes.entry:recorder',
            'sim_clock = softseq_ros.nodes.entry:sim_clock',
            'rig = softseq_ros.nodes.entry:rig',
        ],
    },
)
