from tacbench.cli import main

main()
