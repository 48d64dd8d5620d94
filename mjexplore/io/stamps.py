"""Message stamps: simulated time as the integers MCAP and ROS messages carry."""


def sim_ns(t: float) -> int:
    """Simulated time ``t`` in seconds as whole nanoseconds."""
    return int(round(t * 1e9))


def sec_nsec(t: float) -> tuple[int, int]:
    """Simulated time ``t`` in seconds as (seconds, nanoseconds) of a message stamp."""
    return divmod(sim_ns(t), 1_000_000_000)
