"""`python -m app [--host H] [--port P] [--encoder E] [--corpus DIR]`: load and serve."""

from app.app import main

if __name__ == "__main__":  # not in a model process (`--model-processes`), which spawns
    main()
