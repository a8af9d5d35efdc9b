"""Running the roles: the supervisor (the asynchronous scheduler), placement, calls in process or on Ray, failures,
health, reaping."""
