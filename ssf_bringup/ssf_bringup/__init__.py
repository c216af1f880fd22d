"""SSF-PAN bringup: the application that starts the graph (the `ssf` entry point, `ssf demo`, `ssf launch`, graphs)."""
