from glob import glob

from setuptools import find_packages, setup

package_name = 'softsnap_gaits'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/scenes', glob('scenes/*.yaml')),
        ('share/' + package_name + '/launch', glob('launch/*.py')),
        ('share/' + package_name + '/rviz', glob('rviz/*.rviz')),
    ],
    install_requires=['setuptools', 'pyyaml'],
    zip_safe=True,
    maintainer='SoftSnap developers',
    maintainer_email='softsnap@example.org',
    description='Robot scenes, gaits, gait node and rerun logger for SoftSnap robots.',
    license='MIT',
    entry_points={
        'console_scripts': [
            'gait_node = softsnap_gaits.gait_node:main',
            'rerun_logger = softsnap_gaits.rerun_logger:main',
            'demo = softsnap_gaits.demo:main',
            'bag = softsnap_gaits.bag:main',
            'shape_controller = softsnap_gaits.shape_controller_node:main',
            'softsnap = softsnap_gaits.command_line:main',
        ],
    },
)
