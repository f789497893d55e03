from setuptools import find_packages, setup

package_name = 'softsnap_driver'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='SoftSnap developers',
    maintainer_email='softsnap@example.org',
    description='Driver node per Wi-Fi SoftSnap module and a simulated module.',
    license='MIT',
    entry_points={
        'console_scripts': [
            'driver_node = softsnap_driver.driver_node:main',
            'driver_container = softsnap_driver.driver_container:main',
            'sim_module = softsnap_driver.sim_module:main',
            'sim_robot = softsnap_driver.sim_robot_runner:main',
        ],
    },
)
