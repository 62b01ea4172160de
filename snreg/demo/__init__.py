"""Everything simulated, with its ground truth: the rendered Firefly pair, checkerboard and pivot scenes, the IMU
simulator on a pseudo-terminal, synthetic SPECT, the phantom, the demo rig and the headless demo.

Only the studies (:mod:`snreg.simulation`) and the front ends import it: the devices, algorithms and
coordination below know nothing of simulation, and real and simulated devices meet at the interfaces
(:class:`~snreg.sources.FrameSource`, the serial port, the rig protocols).
"""
