from glob import glob

from setuptools import find_packages, setup

package_name = 'softsnap_model'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
    ],
    install_requires=['setuptools', 'numpy', 'scipy', 'pyyaml'],
    zip_safe=True,
    maintainer='SoftSnap developers',
    maintainer_email='softsnap@example.org',
    description='Quasi-static SoftSnap module model and the model node.',
    license='MIT',
    entry_points={
        'console_scripts': [
            'model_node = softsnap_model.model_node:main',
            'softsnap-model = softsnap_model.cli:main',
            'robot_state = softsnap_model.robot_state_node:main',
        ],
    },
)
