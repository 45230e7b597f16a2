"""One module per `flightrecon` subcommand; each exposes `register(subparsers)`."""
