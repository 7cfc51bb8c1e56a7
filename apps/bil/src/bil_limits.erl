%% @doc Internal. Resolves the size and depth limits a parse runs under:
%% the caller's, else the `bil' application's environment, else built-in
%% defaults.
-module(bil_limits).

-export([resolve/2]).

-export_type([resolved/0]).

-type resolved() :: #{max_size := pos_integer(), max_depth := pos_integer()}.

-define(DEFAULT_SIGNAL_SIZE, 65536).
-define(DEFAULT_DESCRIPTION_SIZE, 1048576).
-define(DEFAULT_DEPTH, 32).

-spec resolve(signal | description, bil:limits()) -> resolved().
resolve(Kind, Limits) ->
    {SizeKey, SizeDefault} = case Kind of
                                 signal -> {max_signal_size, ?DEFAULT_SIGNAL_SIZE};
                                 description -> {max_description_size, ?DEFAULT_DESCRIPTION_SIZE}
                             end,
    #{max_size => limit(max_size, Limits, SizeKey, SizeDefault),
      max_depth => limit(max_depth, Limits, max_depth, ?DEFAULT_DEPTH)}.

limit(Key, Limits, EnvKey, Default) ->
    case Limits of
        #{Key := Value} when is_integer(Value), Value > 0 -> Value;
        _ -> application:get_env(bil, EnvKey, Default)
    end.
