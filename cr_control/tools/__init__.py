"""The command-line programs (cr_session, cr_benchmark, cr_param, cr_lifecycle, cr_fuzz,
cr_identify_tool) and the composed-mode container: the top layer, importing any other.

A program loads what a command needs when the command runs (imports marked ``# lazy``):
``--help`` and a refused argument answer without loading ROS or the compiled laws.
"""
