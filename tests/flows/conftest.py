from tests.flows.harness import prefect_server, use_test_prefect_home  # noqa: F401 (fixture)

use_test_prefect_home()
