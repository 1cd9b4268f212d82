"""Python client of the MAGNET service: `Client(url, token).agglomerate("mesh.vtu", "out.vtu", k=64)`."""

from magnet_client.client import Client, InputError, JobFailed, MagnetHTTPError

__all__ = ["Client", "InputError", "JobFailed", "MagnetHTTPError"]
__version__ = "0.1.0"
