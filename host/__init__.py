"""Host side of clholo: the OpenCL runtime and the schedulers that drive the kernels."""

from .runtime import (  # noqa: F401
    DeviceInfo,
    EventTimer,
    NoDeviceError,
    ProgramBuildError,
    build_program,
    choose_device,
    create_queue,
    event_seconds,
    get_context,
    get_kernel,
    get_queue,
    has_fp64,
    kernel_dir,
    list_devices,
    require_fp64,
)
