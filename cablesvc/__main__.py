from cablesvc.cli.main import main

# guarded: the worker processes of a LocalCluster (cablesvc discover/identify over many
# recordings) are spawned and import the main module again; they must not run the CLI
if __name__ == "__main__":
    raise SystemExit(main())
