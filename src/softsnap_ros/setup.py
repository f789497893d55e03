from setuptools import find_packages, setup

package_name = 'softsnap_ros'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    # The Fast DDS profile every node loads (softsnap_ros.spinning.init_ros).
    package_data={package_name: ['fastdds_profile.xml']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='SoftSnap developers',
    maintainer_email='softsnap@example.org',
    description='The ROS plumbing every SoftSnap node stands on: node base, spinning, '
                'wait loop, DDS profile, CDR codec, units.',
    license='MIT',
)
