"""``seedmap config show``: the configuration a command runs with, as commented YAML."""
