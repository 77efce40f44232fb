"""Autonomous fingertip capture, pure (no ROS, no libqi): the robot presses its own fingertip on a skin part.

:mod:`~nao_skin.capture.plan` chooses the next taxel, solves a pose for the fingertip a few centimetres off it
(inverse kinematics within the joint limits less a margin, the arm clear of the body) and the straight approach
along the skin's normal; :mod:`~nao_skin.capture.safety` is the gate every command and every reading passes
(each stop a one-line reason); :mod:`~nao_skin.capture.loop` runs the touches against an ALMotion-shaped
``Motion`` and a contact source, so the same loop drives the simulated body in the tests
(:mod:`nao_skin.sim.body`) and the robot through the ``fingertip_capture`` node.
"""
