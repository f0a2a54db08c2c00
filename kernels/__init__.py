"""OpenCL C sources of clholo (package data: the .cl and .h files beside this file).

Load them through :func:`clholo.host.runtime.build_program`, never by path.
"""
