"""Which gateway talks to which vehicle: assignment by what each gateway hears, pins, command dispatch."""
