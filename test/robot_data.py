"""Whether example-robot-data (the Panda's and UR5's URDFs) is installed, as a skip mark."""

import pytest

from cr_control.models.urdf import package_share


def example_robot_data_installed() -> bool:
    try:
        package_share("example-robot-data")
    except ValueError:
        return False
    return True


needs_erd = pytest.mark.skipif(not example_robot_data_installed(),
                               reason="example-robot-data not installed")
