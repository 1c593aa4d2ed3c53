"""ament_python package definition for mantis_rig (also installable with pip)."""
import os

from setuptools import find_packages, setup

PACKAGE = 'mantis_rig'


def config_data_files():
    """Install config/ (the Foxglove layout) under share/mantis_rig/config, keeping its
    sub-folders. The scenes are mantis_sim's package data (mantis_sim/scenes/)."""
    entries = []
    for folder, _, files in os.walk('config'):
        data = [os.path.join(folder, f) for f in files if f.endswith(('.yaml', '.yml', '.json'))]
        if data:
            entries.append((os.path.join('share', PACKAGE, folder), data))
    return entries


NODES = {
    'stage_node': 'mantis_rig.nodes.stage_node:main',
    'loadcell_node': 'mantis_rig.nodes.loadcell_node:main',
    'camera_node': 'mantis_rig.nodes.camera_node:main',
    'supervisor_node': 'mantis_rig.nodes.supervisor_node:main',
    'sim_rig': 'mantis_rig.simulated.sim_rig:main',
    'replay_node': 'mantis_rig.nodes.replay_node:main',
}
EXISTING_NODES = [
    f'{name} = {target}' for name, target in NODES.items()
    if os.path.exists(os.path.join(*target.split(':')[0].split('.')) + '.py')
]

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*', 'bench', 'bench.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/launch', ['launch/mantis_rig.launch.py']),
        *config_data_files(),
    ],
    package_data={'mantis_sim': ['scenes/*.yaml']},
    install_requires=['setuptools'],
    extras_require={
        'nidaq': ['nidaqmx==1.7.0'],
        # the design studies (mantis_sim.studies: mantis sweep, sweep-plot); pins as in
        # requirements.txt, which installs them for the project's own .venv
        'studies': ['dask==2026.8.0', 'distributed==2026.8.0', 'pyarrow==26.0.1',
                    'threadpoolctl==3.8.0', 'statsmodels==0.15.0'],
    },
    zip_safe=False,     # the scenes are read as files from the installed package
    maintainer='mantis_rig maintainers',
    maintainer_email='mantis-rig@example.org',
    description='Mantis-shrimp robot rig: device nodes, logging, replay, analysis and simulation',
    license='MIT',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': ['mantis = mantis_rig.cli:main', *EXISTING_NODES],
    },
)
