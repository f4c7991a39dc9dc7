"""nidaqmx.stream_writers.AnalogSingleChannelWriter (write_one_sample)."""


class AnalogSingleChannelWriter:
    def __init__(self, task_out_stream, auto_start=True) -> None:
        self._task = task_out_stream._task
        self.auto_start = auto_start

    def write_one_sample(self, data, timeout=10.0):
        self._task.write(float(data), auto_start=self.auto_start, timeout=timeout)
