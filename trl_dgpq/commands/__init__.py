"""The suite's commands; ``scripts/<name>.py`` runs ``trl_dgpq.commands.<name>.main``."""
