"""nidaqmx.errors: DaqError carries NI's error code."""


class Error(Exception):
    pass


class DaqError(Error):
    def __init__(self, message: str, error_code: int, task_name: str = "") -> None:
        text = f"{message}\n\nStatus Code: {error_code}"
        if task_name:
            text += f"\nTask Name: {task_name}"
        super().__init__(text)
        self._error_code = int(error_code)

    @property
    def error_code(self) -> int:
        return self._error_code
