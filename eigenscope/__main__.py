from eigenscope.cli import console_main

console_main()
