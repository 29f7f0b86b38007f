from d2a_cli.main import main

main()
