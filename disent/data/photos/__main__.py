from disent.data.photos.study import main

main()
