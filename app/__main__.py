"""`python -m app [--host H] [--port P] [--encoder E] [--corpus DIR]`: load and serve."""

from app.app import main

main()
