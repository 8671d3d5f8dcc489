from ndfa.cli.app import main

main()
