"""Metrics and figures: of recorded sessions (``cr_analyze``: session_file, metrics, plots)
and of the thesis's chapters (chapter2/4/5/6, from sessions or offline runs).

Reading a recorded session loads no control law, plant or offline runner (they bring the
compiled kernels): the chapter modules import those inside the functions that run or model
a scheme (``offline_run``, ``true_estimates`` ...), each marked ``# lazy``;
test/test_import_contract.py checks that importing ``cr_analyze`` loads none of them.
"""
