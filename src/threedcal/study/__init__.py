"""The study layer: the config parsed and checked, the workflow's files, and the stages that compose
the domain packages for one rule each. Domain packages never import from here."""
