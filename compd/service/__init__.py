"""The daemon: config, driver links, the tick loop, safety, state, recorder and control socket."""
