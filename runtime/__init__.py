"""What every covswarm process shares besides the wire protocol: clocks and stopping,
id claims, and the command-line options common to several processes."""
