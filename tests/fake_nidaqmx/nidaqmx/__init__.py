"""A strict fake of NI's ``nidaqmx`` Python package (the parts pmalab uses), for tests.

Same names and signatures as nidaqmx-python 1.x (``Task``, ``task.ai_channels.
add_ai_voltage_chan``, ``task.ao_channels.add_ao_voltage_chan``, ``task.timing.
cfg_samp_clk_timing``, ``task.in_stream.avail_samp_per_chan``, ``stream_readers.
AnalogMultiChannelReader.read_many_sample``, ``task.read``/``task.write``, ``errors.DaqError``
with NI's error codes), refusing what the real driver refuses: a read before ``start()``
(−200473), a buffer too small for the rate (−200608), an unsupported rate or range (−200077),
a channel the device does not have (−200170), configuring a running task (−200479), any use
of a closed task (−200088).  Behind it, :mod:`nidaqmx._device` simulates the muscle rig the
channels are wired to (pmalab's simulated physics, sensors as voltages).
"""

from nidaqmx import constants, errors, stream_readers, stream_writers
from nidaqmx.errors import DaqError
from nidaqmx.task import Task

__all__ = ["DaqError", "Task", "constants", "errors", "stream_readers", "stream_writers"]
