from disent.report import main

main()
