"""Commands: the lifecycle of a control packet from queued to executed, signing, history."""
