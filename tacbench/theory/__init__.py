"""The paper's theory, exactly and in NumPy: the q-exponential and q-logarithm, the Tsallis
entropy, the q-max and q-softmax (``tsallis``), Tsallis MDPs solved by policy and value iteration
with the performance bounds (``mdp``), and the paper's theory figures with their CSVs
(``figures``, ``tacbench figures``). Nothing here trains an agent."""
