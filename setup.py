"""ament_python package definition for nao_skin.

Works both in a real ROS 2 colcon workspace (``colcon build``) and in the
plain pip venv made by ``docker/setup_venv.sh`` (``pip install -e .``).
"""
import os
from glob import glob

from setuptools import find_packages, setup

package_name = 'nao_skin'
here = os.path.dirname(os.path.abspath(__file__))


def files(pattern):
    """Files (not dirs, not .gitkeep) matching ``pattern``, relative to here.

    Tolerates empty or missing directories: it then returns an empty list.
    """
    out = []
    for path in sorted(glob(os.path.join(here, pattern))):
        if os.path.isfile(path) and os.path.basename(path) != '.gitkeep':
            out.append(os.path.relpath(path, here))
    return out


share = os.path.join('share', package_name)
data_files = [
    ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
    (share, ['package.xml']),
    (os.path.join(share, 'launch'), files('launch/*.py')),
    (os.path.join(share, 'config'), files('config/*')),
    (os.path.join(share, 'config', 'layouts'), files('config/layouts/*')),
    (os.path.join(share, 'urdf'), files('urdf/*')),
]
# the bundled recording (bags/sim_default/...), directory structure kept
for dirpath, _, _ in sorted(os.walk(os.path.join(here, 'bags'))):
    rel = os.path.relpath(dirpath, here)
    data_files.append((os.path.join(share, rel), files(os.path.join(rel, '*'))))
# setuptools is fine with empty lists, but keep the metadata clean.
data_files = [(dest, srcs) for dest, srcs in data_files if srcs]

setup(
    name=package_name,
    version='0.1.0',
    package_dir={'': 'src'},
    packages=find_packages('src'),
    data_files=data_files,
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='nao_skin dev',
    maintainer_email='nao_skin@example.com',
    description='Artificial skin for the NAO robot (ROS 2).',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'nao-skin = nao_skin.entry:nao_skin',
            'calibrate = nao_skin.entry:calibrate',
            'naoqi_bridge = nao_skin.entry:naoqi_bridge',
            'yarp_skin_bridge = nao_skin.entry:yarp_skin_bridge',
            'sim_robot = nao_skin.entry:sim_robot',
            'pairing_recorder = nao_skin.entry:pairing_recorder',
            'skin_heatmap = nao_skin.entry:skin_heatmap',
            'fingertip_capture = nao_skin.entry:fingertip_capture',
        ],
    },
)
