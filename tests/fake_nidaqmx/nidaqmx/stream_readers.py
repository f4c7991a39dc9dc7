"""nidaqmx.stream_readers.AnalogMultiChannelReader (read_many_sample into a 2-D float64 array)."""

import numpy as np

from nidaqmx.constants import READ_ALL_AVAILABLE
from nidaqmx.errors import DaqError


class AnalogMultiChannelReader:
    def __init__(self, task_in_stream) -> None:
        self._in_stream = task_in_stream
        self._task = task_in_stream._task
        self.verify_array_shape = True

    def read_many_sample(self, data, number_of_samples_per_channel=READ_ALL_AVAILABLE,
                         timeout=10.0):
        task = self._task
        n = number_of_samples_per_channel
        if n == READ_ALL_AVAILABLE:
            n = self._in_stream.avail_samp_per_chan
        if not isinstance(data, np.ndarray) or data.dtype != np.float64:
            raise DaqError("Read cannot be performed: the array is not float64.", -200525)
        if self.verify_array_shape and data.shape != (len(task._ai), n):
            raise DaqError(f"Read cannot be performed because the NumPy array passed into this "
                           f"function is not shaped correctly. You must pass in a NumPy array "
                           f"of the correct shape based on the number of channels in task and "
                           f"the number of samples per channel requested.\n\nShape of NumPy "
                           f"Array provided: {data.shape}\nShape of NumPy Array required: "
                           f"{(len(task._ai), n)}", -1)
        block = task._acquire(n, timeout)
        data[:, : block.shape[1]] = block
        return block.shape[1]
