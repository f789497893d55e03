from glob import glob

from setuptools import find_packages, setup

package_name = 'softsnap_vision'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
    ],
    install_requires=['setuptools', 'numpy', 'scipy', 'pyyaml', 'opencv-python-headless'],
    zip_safe=True,
    maintainer='SoftSnap developers',
    maintainer_email='softsnap@example.org',
    description='Camera measurement of SoftSnap module shapes (OpenCV core) and the marker tracker node.',
    license='MIT',
    entry_points={
        'console_scripts': [
            'marker_tracker = softsnap_vision.marker_tracker_node:main',
            'softsnap-measure = softsnap_vision.measure:main',
            'softsnap-validate = softsnap_vision.validation:main',
            'softsnap-calibrate-camera = softsnap_vision.calibrate_camera:main',
        ],
    },
)
